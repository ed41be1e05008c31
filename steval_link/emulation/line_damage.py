"""A loose wire on header P7, as bytes: bit flips, cut bytes and garbage bursts, and the score of a decoder on it.

:func:`long_stream` turns a capture into as many unique, plausible frames as wanted; :func:`damage` hurts them;
:func:`score` tells which decoded frames were sent (recovered) and which never were (fake).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from steval_link import constants as C
from steval_link.link import protocol as P


@dataclass
class DamageCounts:
    """How many damage events of each kind :func:`damage` made."""

    flips: int = 0
    cuts: int = 0
    bursts: int = 0


def damage(data: bytes, rng: np.random.Generator) -> tuple[bytes, DamageCounts]:
    """``data`` with one damage event every 200 .. 5000 bytes (uniform): a single bit flip (60 %), a cut of 1 .. 16
    bytes (20 %) or a burst of 1 .. 64 random bytes inserted (20 %)."""
    n = len(data)
    pos = np.cumsum(rng.integers(200, 5000 + 1, size=n // 200 + 2))
    pos = pos[pos < n]
    out = bytearray()
    counts = DamageCounts()
    last = 0
    for p, k in zip(pos.tolist(), rng.random(len(pos)).tolist()):
        if p < last:
            continue
        out += data[last:p]
        if k < 0.6:
            out.append(data[p] ^ (1 << int(rng.integers(8))))
            last = p + 1
            counts.flips += 1
        elif k < 0.8:
            last = p + int(rng.integers(1, 16 + 1))
            counts.cuts += 1
        else:
            out += rng.integers(0, 256, int(rng.integers(1, 64 + 1)), dtype=np.uint8).tobytes()
            last = p
            counts.bursts += 1
    out += data[last:]
    return bytes(out), counts


def long_stream(att: np.ndarray, sta: np.ndarray, n_frames: int, start_rep: int = 0) -> tuple[bytes, list[bytes]]:
    """About ``n_frames`` v2 attitude frames (and the status frames among them) of the records ``att`` and ``sta``
    (consecutive steps), repeated with ``seq``, ``step`` and ``t_us`` continued from repetition ``start_rep``.
    Returns the bytes and the frames' payloads (what a perfect decoder hands out)."""
    n = len(att)
    out = bytearray()
    payloads: list[bytes] = []
    row_of_seq = {int(q): i for i, q in enumerate(att["seq"])}
    sta_after = {}
    for s in sta:
        i = row_of_seq.get(int(s["step"]) % P.SEQ_MODULUS)
        if i is not None:
            sta_after[i] = s
    for r in range(start_rep, start_rep - (-n_frames // n)):  # ⌈n_frames / n⌉ repetitions
        a = att.copy()
        shift = r * n
        a["seq"] = (a["seq"].astype(np.int64) + shift) % P.SEQ_MODULUS
        a["t_us"] = (a["t_us"].astype(np.int64) + int(round(shift * C.AHRS_PERIOD_US))) % P.T_US_MODULUS
        block = P.encode_attitude_block(a)
        fs = P.ATTITUDE_FRAME_SIZE
        for i in range(n):
            out += block[i * fs : (i + 1) * fs]
            payloads.append(a[i].tobytes())
            s = sta_after.get(i)
            if s is not None:
                s2 = s.copy()
                s2["step"] = (int(s["step"]) + shift) % (1 << 32)
                s2["t_us"] = (int(s["t_us"]) + int(round(shift * C.AHRS_PERIOD_US))) % P.T_US_MODULUS
                out += P.encode_frame(P.TYPE_STATUS, s2.tobytes())
                payloads.append(s2.tobytes())
    return bytes(out), payloads


@dataclass
class FuzzScore:
    """Frames sent, recovered (decoded and sent) and fake (decoded, never sent)."""

    sent: int = 0
    recovered: int = 0
    fake: int = 0

    def add(self, other: "FuzzScore") -> None:
        self.sent += other.sent
        self.recovered += other.recovered
        self.fake += other.fake

    @property
    def recovered_ratio(self) -> float:
        return self.recovered / self.sent if self.sent else 0.0


def payload_records(tel) -> tuple[np.ndarray, np.ndarray]:
    """The binary attitude and status rows of a decoded ``Telemetry`` as wire payload records, field for field."""
    out = []
    for rows, dtype in ((tel.attitude, P.ATTITUDE_DTYPE), (tel.status, P.STATUS_DTYPE)):
        rec = np.zeros(len(rows), dtype)
        for name in dtype.names:
            rec[name] = getattr(rows, name)
        out.append(rec[rows.exact])
    return out[0], out[1]


def score(sent_payloads: list[bytes], tel) -> tuple[FuzzScore, list[bytes]]:
    """The score of a decoded ``Telemetry``'s attitude and status frames against the payloads sent, and the fakes."""
    sent = set(sent_payloads)
    got = [r.tobytes() for rows in payload_records(tel) for r in rows]
    fakes = [g for g in got if g not in sent]
    return FuzzScore(sent=len(sent_payloads), recovered=len(got) - len(fakes), fake=len(fakes)), fakes
