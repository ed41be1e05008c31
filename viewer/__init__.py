"""The Rerun side of steval-link (imported as ``steval_viewer``): blueprint, entity layout, drone model, logging."""
