"""A live session (``steval live``, ``steval record``): recorder (reader thread), pipeline, estimators, health,
session. See :mod:`steval_link.live.session`."""
