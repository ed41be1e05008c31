"""A live session over one source interface (``steval live``, ``record``, ``emulate``): :mod:`.session`."""
