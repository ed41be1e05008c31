"""Attitude estimators over arrays in the firmware's units: the bit-exact ST Mahony replica, accelerometer-only tilt,
the EKFs, VQF; the registry that names them."""
