"""Analyses of captures: compare (firmware vs port, EKFs, accel tilt), evaluate (against ground truth), plots."""
