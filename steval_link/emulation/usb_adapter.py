"""The host side of an emulated capture: a USB-UART adapter (FTDI FT232R-like) that delivers the serial bytes in
USB packets, with the receive times a reader on the host sees (``steval synth``)."""

from __future__ import annotations

import math

import numpy as np

from steval_link import constants as C

#: data bytes per USB packet, latency timer, USB frame
ADAPTER_PACKET_BYTES = 62
ADAPTER_LATENCY_S = 0.016
USB_FRAME_S = 0.001


def host_chunks(stream: bytes, sizes, starts, tau: float, join_at_s: float, rng, total_s: float):
    """Bytes the host receives in [join, join + duration] and their USB packets' receive times.

    Returns ``((first, end) stream offsets of the captured bytes, chunk offsets, chunk times s since start)``.
    """
    n = len(stream)
    if n == 0:
        return (0, 0), np.zeros(0, np.int64), np.zeros(0)
    frame_off = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    rep_start = np.repeat(starts, sizes)
    idx = np.arange(n, dtype=np.float64) - np.repeat(frame_off, sizes)
    end_s = (rep_start + (idx + 1) * tau) / C.CPU_HZ  # the stop bit of each byte is out
    join = float(join_at_s)
    first = int(np.searchsorted(end_s, join, side="right")) if join > 0 else 0
    e = end_s[first:]
    # adapter: a packet when 62 bytes are in, or when the latency timer expires with data waiting
    sof_phase = rng.uniform(0.0, USB_FRAME_S)
    t_last = (e[0] if len(e) else 0.0) - rng.uniform(0.0, ADAPTER_LATENCY_S)
    flush_t, flush_end = [], []
    i, m = 0, len(e)
    while i < m:
        k = max(1, math.ceil((e[i] - t_last) / ADAPTER_LATENCY_S - 1e-12))
        expiry = t_last + k * ADAPTER_LATENCY_S
        j_full = i + ADAPTER_PACKET_BYTES - 1
        if j_full < m and e[j_full] <= expiry:
            t_f, j = e[j_full], j_full
        else:
            j = int(np.searchsorted(e, expiry, side="right")) - 1
            t_f = expiry
        flush_t.append(t_f)
        flush_end.append(j + 1)
        t_last = t_f
        i = j + 1
    flush_t = np.array(flush_t)
    # USB: the host controller picks the packet up at the next 1 ms frame; the OS hands it to the reader later
    arrive = sof_phase + np.ceil((flush_t - sof_phase) / USB_FRAME_S) * USB_FRAME_S
    arrive = arrive + rng.exponential(0.00015, len(arrive))
    arrive = np.maximum.accumulate(arrive)
    keep = arrive <= total_s
    flush_end = np.array(flush_end, dtype=np.int64)[keep]
    arrive = arrive[keep]
    n_cap = int(flush_end[-1]) if len(flush_end) else 0
    chunk_offsets = np.concatenate(([0], flush_end[:-1])) if len(flush_end) else np.zeros(0, np.int64)
    return (first, first + n_cap), chunk_offsets.astype(np.int64), arrive - join
