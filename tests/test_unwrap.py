"""``seq`` and ``t_us`` unwrapping: one implementation for the bulk decoder and the live path, so both give the same
steps and times however a stream is cut into batches."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from steval_link.link import protocol as P
from steval_link.link.telemetry import SeqUnwrapper, TimeUnwrapper


def _stream(draw_ops, start: int) -> np.ndarray:
    """Full steps of a stream: runs of frames with gaps, repeats and firmware restarts."""
    out, step = [], start
    for op, k in draw_ops:
        if op == "run":
            out += list(range(step, step + k))
            step += k
        elif op == "gap":
            step += k
        elif op == "repeat" and out:
            out.append(out[-1])
        elif op == "restart":
            step = 0
    return np.array(out, dtype=np.int64)


ops = st.lists(
    st.tuples(st.sampled_from(["run", "run", "gap", "repeat", "restart"]), st.integers(1, 30000)),
    min_size=1,
    max_size=12,
)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@settings(max_examples=200, derandomize=True, database=None)
@given(ops=ops, start=st.integers(0, 2**20), cuts=st.lists(st.integers(0, 10**6), max_size=6))
def test_streaming_in_any_batches_equals_one_bulk_call(ops, start, cuts):
    full = _stream(ops, start)
    if full.size == 0:
        return
    seq = full % P.SEQ_MODULUS
    bulk, bulk_restart = SeqUnwrapper().steps(seq)
    u = SeqUnwrapper()
    edges = sorted({0, len(seq), *(c % (len(seq) + 1) for c in cuts)})
    parts = [u.steps(seq[a:b]) for a, b in zip(edges[:-1], edges[1:])]
    streamed = np.concatenate([p[0] for p in parts])
    assert np.array_equal(streamed, bulk)
    assert np.array_equal(np.concatenate([p[1] for p in parts]), bulk_restart)


def test_seq_wraps_repeats_and_restarts():
    u = SeqUnwrapper()
    steps, restart = u.steps([65534, 65535, 0, 2, 2])
    assert steps.tolist() == [65534, 65535, 65536, 65538, 65538] and not restart.any()
    steps, restart = u.steps([1, 2])  # back: the firmware restarted
    assert steps.tolist() == [1, 2] and restart.tolist() == [True, False]
    u.status(3 * 65536 + 2)  # a status frame names the full step
    assert u.steps([3])[0].tolist() == [3 * 65536 + 3]
    u.status(7)  # one that disagrees is ignored
    assert u.steps([4])[0].tolist() == [3 * 65536 + 4]


def test_time_wraps_once_per_71_minutes_and_small_steps_back_are_not_wraps():
    m = P.T_US_MODULUS
    u = TimeUnwrapper()
    t = u.seconds([m - 2_000_000, m - 1_000_000, 500_000])
    assert np.allclose(t, [(m - 2e6) / 1e6, (m - 1e6) / 1e6, (m + 5e5) / 1e6])
    assert u.seconds([400_000])[0] == (m + 400_000) / 1e6  # 0.1 s back: a repeated/early time, not a wrap
    assert u.nearest(m - 1) == (m - 1) / 1e6  # just before the wrap: placed before it
    assert u.wraps == 1
