"""Builders of synthetic wire streams that remember what they sent (for decoder, capture and CLI tests)."""

from __future__ import annotations

import math

import numpy as np

from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder
from steval_link.link.textmode import format_att, format_sta


class StreamBuilder:
    """Builds wire streams frame by frame and remembers what was sent (frame bytes, kind, key values)."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.parts: list[bytes] = []
        self.sent: list[tuple[str, bytes, object]] = []  # (kind, exact frame bytes, key)

    def _add(self, kind: str, frame: bytes, key) -> bytes:
        self.parts.append(frame)
        self.sent.append((kind, frame, key))
        return frame

    def attitude(self, step: int, t_us: int | None = None, thr: int = 0) -> bytes:
        r = self.rng
        t_us = int(step * 6191.9) if t_us is None else t_us
        frame = P.encode_attitude(
            t_us=t_us,
            acc_mg=r.normal([0, 0, 1000], 30, 3).astype(np.float32),
            gyro_mdps=r.normal(0, 800, 3).astype(np.float32),
            q_wxyz=np.array([0.9983, r.normal(0, 0.05), r.normal(0, 0.05), 0.01], np.float32),
            thz_rad=np.float32(r.normal()),
            seq=step,
            thr=thr,
        )
        return self._add("attitude", frame, step % P.SEQ_MODULUS)

    def status(self, step: int, t_us: int | None = None, **kw) -> bytes:
        t_us = int(step * 6191.9) if t_us is None else t_us
        frame = P.encode_status(step=step, t_us=t_us, q_wxyz=[0.9983, 0, 0, 0], int_xyz=[1e-4, -2e-4, 0], **kw)
        return self._add("status", frame, step)

    def text(self, line: str) -> bytes:
        frame = P.encode_text(line)
        return self._add("text", frame, line)

    def att_line(self, step: int, t_ms: int | None = None) -> bytes:
        r = self.rng
        t_ms = int(step * 6.1919) if t_ms is None else t_ms
        line = format_att(
            step=step,
            t_ms=t_ms,
            thr=0,
            thx_mdeg=int(r.integers(-90000, 90000)),
            thy_mdeg=int(r.integers(-90000, 90000)),
            thz_mdeg=int(r.integers(-180000, 180000)),
            acc_mg=r.integers(-2000, 2000, 3),
            gyro_mdps=r.integers(-100000, 100000, 3),
        )
        return self._add("att_line", line, step)

    def sta_line(self, step: int) -> bytes:
        line = format_sta(
            step=step,
            t_ms=int(step * 6.1919),
            cyc_min=1000,
            cyc_mean=1100,
            cyc_max=1500,
            cyc_n=161,
            tx_dropped=0,
            flags=P.FLAG_TEXT_MODE,
            ki_micro=100000,
        )
        return self._add("sta_line", line, step)

    def log_line(self, text: str) -> bytes:
        return self._add("log_line", text.encode() + b"\r\n", text)

    def flight(self, n: int, start: int = 0, status_every: int = 161, text_every: int = 0) -> "StreamBuilder":
        """``n`` attitude frames from step ``start``, a status frame after every ``status_every``th."""
        for i in range(start, start + n):
            self.attitude(i)
            if status_every and i % status_every == status_every - 1:
                self.status(i)
            if text_every and i % text_every == text_every - 1:
                self.text(f"log line at step {i}")
        return self

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def frame_keys(frames) -> list[tuple]:
    """Comparable identity of decoded frames (kind-specific fields + offset)."""
    from steval_link.link.frames import AttitudeFrame, StatusFrame

    out = []
    for f in frames:
        if isinstance(f, AttitudeFrame):
            out.append(
                (
                    "a",
                    f.offset,
                    f.seq,
                    f.t_us,
                    f.exact,
                    f.step,
                    *f.acc_mg,
                    *f.gyro_mdps,
                    *(0.0 if math.isnan(x) else x for x in f.q_wxyz),
                )
            )
        elif isinstance(f, StatusFrame):
            out.append(("s", f.offset, f.step, f.t_us, f.exact))
        else:
            out.append(("t", f.offset, f.text))
    return out


def stream_decode(data: bytes, chunk: int | list[int] = 4096, *, plausibility: bool = True):
    """``data`` through one :class:`StreamDecoder` as a port delivers it: in chunks of ``chunk`` bytes (a list: of
    those sizes, then the rest), then ``finish()``. Returns (frames, stats)."""
    sd = StreamDecoder(plausibility=plausibility)
    frames = []
    if isinstance(chunk, int):
        for i in range(0, len(data), chunk):
            frames += sd.feed(data[i : i + chunk])
    else:
        pos = 0
        for c in chunk:
            frames += sd.feed(data[pos : pos + c])
            pos += c
        frames += sd.feed(data[pos:])
    frames += sd.finish()
    return frames, sd.stats
