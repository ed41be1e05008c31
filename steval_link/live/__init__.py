"""A live session (``steval live``, ``record``, ``emulate``, ``live --ble``): one session over one source interface
(serial port or replay, emulated board, BLE), recorder, pipeline, estimators, health. See
:mod:`steval_link.live.session`."""
