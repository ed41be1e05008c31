"""A live session (``steval live``, ``record``, ``emulate``, ``live --ble``) over one source interface: see
:mod:`steval_link.live.session`."""
