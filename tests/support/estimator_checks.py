"""Checks every host estimator's interface must pass (``run`` and ``step`` agree; bad samples do no harm)."""

from __future__ import annotations

import numpy as np


def assert_run_equals_steps(est, acc_mg, gyro_mdps) -> None:
    """``est.run`` over the rows gives what ``est.step`` gives row by row after ``est.reset()``."""
    q_run = est.run(acc_mg, gyro_mdps).q_wxyz
    est.reset()
    q_step = np.array([est.step(a, g) for a, g in zip(acc_mg, gyro_mdps)])
    assert np.allclose(q_run, q_step)


def assert_bad_samples_harmless(est, samples) -> None:
    """After stepping through ``samples`` ((acc_mg, gyro_mdps) pairs: zeros, NaN), a level sample gives a finite
    quaternion: nothing poisoned the state."""
    for acc_mg, gyro_mdps in samples:
        est.step(acc_mg, gyro_mdps)
    assert np.all(np.isfinite(est.step([0, 0, 1000], [0, 0, 0])))
