"""Attitude estimators: the bit-exact ST Mahony port, accelerometer-only tilt, EKFs, and the sensor pipeline model."""
