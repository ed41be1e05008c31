"""The Rerun side of steval-link (imported as ``steval_viewer``): blueprint, entity layout, drone model, logging."""

import os as _os

#: Rerun's own log lines never reach the user's terminal (steval says what went wrong in its own sentence); set
#: before Rerun is first imported, a user's ``RUST_LOG`` wins. ``QUIETED_RUST_LOG``: whether we set it.
QUIETED_RUST_LOG = "RUST_LOG" not in _os.environ
if QUIETED_RUST_LOG:
    _os.environ["RUST_LOG"] = "off"
