"""Analyses of captures: the replay summary, compare (firmware vs the replica, EKFs, accel tilt: report, link
statistics, diagnosis), evaluate (against ground truth), plots."""
