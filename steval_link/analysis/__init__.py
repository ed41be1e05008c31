"""Analyses of captures: the replay summary, compare (firmware vs port, EKFs, accel tilt: report, link statistics,
diagnosis), evaluate (against ground truth), plots."""
