"""Load a recording into :class:`~steval_link.link.telemetry.Telemetry`: a ``.stv`` capture, a raw byte dump
(``cat /dev/ttyUSB0 > log.bin``) or a text-mode log, told apart by content. Bad input is a one-sentence UserError.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from steval_link.errors import UserError
from steval_link.link.ble_payloads import is_ble_source
from steval_link.link.ble_telemetry import ble_telemetry
from steval_link.link.capture import (
    MAGIC,
    SYMBOL_DTYPE,
    Capture,
    CaptureTruncatedWarning,
    HostChunk,
    capture_symbol_rows,
    read_capture,
    read_file_bytes,
)
from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import CommandFrame
from steval_link.link.telemetry import COMMAND_ROW_DTYPE, AttitudeArrays, Telemetry
from steval_link.link.text_series import FLOATLESS_NOTE


@dataclass
class Recording(Capture):
    """A capture, raw dump or text log; ``kind``: "stv", or "bytes" until decoding tells "raw" from "text"."""

    kind: str = "stv"

    @property
    def line_start(self) -> bool:
        """The first byte starts a line: a log file, or a capture whose header says so (of a log's live replay)."""
        return self.kind != "stv" or bool((self.header.get("extra") or {}).get("line_start"))

    @property
    def warnings(self) -> list[str]:
        """What was wrong with the file (a damaged or cut capture), one sentence each."""
        return [self.warning] if self.warning else []


def read_recording(path: str | os.PathLike) -> Recording:
    """The bytes of ``path``: a ``.stv`` capture (by its magic) or any other file as raw serial bytes."""
    path = Path(path)
    raw = read_file_bytes(path)
    if not raw:
        raise UserError(f"{path} is empty.")
    if raw.startswith(MAGIC) or (path.suffix.lower() == ".stv" and MAGIC.startswith(raw[: len(MAGIC)])):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CaptureTruncatedWarning)
            cap = read_capture(path, data=raw)
        return Recording(**{f.name: getattr(cap, f.name) for f in fields(Capture)}, kind="stv")
    none = np.zeros(0, np.int64)
    return Recording(path, {}, raw, none, none.astype(np.float64), [], kind="bytes")


def load_telemetry(path: str | os.PathLike, *, text_map: dict | None = None) -> Telemetry:
    """Decode a capture, raw byte dump or text-mode log (``source["kind"]``); a truncated capture's warning is issued
    and kept in ``source["warnings"]``. ``text_map`` ({target: (series, unit)}) maps text telemetry to attitude."""
    src = read_recording(path)
    for w in src.warnings:
        warnings.warn(w, CaptureTruncatedWarning, stacklevel=2)
    return telemetry_of_recording(src, text_map=text_map)


def telemetry_of_recording(src: Recording, *, text_map: dict | None = None, ble_layout: str | None = None) -> Telemetry:
    """Decode a :class:`Recording` and its symbol chunks S; ``ble_layout``: a BLE capture's (None: its header's)."""
    if is_ble_source(src):
        return ble_telemetry(src, ble_layout)
    symbols = capture_symbol_rows(src.chunks) if src.kind == "stv" else None
    if src.kind == "stv" and not src.data and symbols is None:
        try:
            size = f"{Path(src.path).stat().st_size} bytes"
        except OSError:
            size = "size unknown"
        if src.warnings:  # cut short or damaged right after the header
            raise UserError(
                f"{src.path}: {size}, a capture header and no readable chunk after it (damaged or cut "
                "short): no frames."
            )
        raise UserError(f"{src.path}: {size}, an empty capture (a header, no bytes were received): no frames.")
    tel = decode_bytes(
        src.data,
        (src.chunk_offsets, src.chunk_times_s),
        baud=src.header.get("baud"),
        source={"path": str(src.path), "kind": src.kind, "header": src.header, "warnings": list(src.warnings)},
        events=src.events,
        sent_commands=sent_command_rows(src.host),
        line_start=src.line_start,
    )
    if text_map:
        if not len(tel.text_series):
            raise UserError(f"{src.path} has no text telemetry to map (no records of numbers found).")
        tel.map_text(text_map)
    if src.kind != "stv":
        if len(tel.attitude) + len(tel.status) + len(tel.text_series) == 0:
            raise UserError(
                f"{src.path} is not a steval capture, raw serial dump or text log (no frames found, and no records "
                f"of numbers, in {len(src.data)} bytes{_text_lines(tel)})."
            )
        tel.source["kind"] = "raw" if tel.binary_rows + int(tel.status.exact.sum()) else "text"
    elif tel.stats.frames_ok == 0 and symbols is None:
        raise UserError(
            f"{src.path}: no frames in {len(src.data)} received bytes (wrong baud rate, or not the steval-link "
            f"firmware?)."
        )
    return merge_symbol_attitude(tel, symbols)


def _text_lines(tel: Telemetry) -> str:
    n = len(tel.text)
    if not n:
        return ""
    said = f"; {n} text line{'s' if n != 1 else ''}"
    texts = [t for _, t in tel.text[:50]]
    if sum(bool(_FLOATLESS.fullmatch(t.strip())) for t in texts) >= min(3, len(texts)):  # "Pitch = \tRoll = "
        said += f", labels with no numbers after them: {FLOATLESS_NOTE[0].lower()}{FLOATLESS_NOTE[1:].rstrip('.')}"
    return said


#: a line of labels with nothing printed after them: a %f of newlib nano (``Drone_Pitch = \tDrone_Roll = ``)
_FLOATLESS = re.compile(r"(?:[A-Za-z_][\w .()/-]*\s*[=:]\s*)+")


def sent_command_rows(host: list[HostChunk]) -> np.ndarray:
    """The command frames of a capture's H chunks as ``COMMAND_ROW_DTYPE`` rows."""
    dec = StreamDecoder()
    rows = []
    for h in host:
        for f in dec.feed(h.data):
            if isinstance(f, CommandFrame):
                rows.append((f.cmd_seq, f.cmd, f.param, f.value, 0, h.offset, f.nbytes, h.t_host_s))
    return np.array(rows, dtype=COMMAND_ROW_DTYPE) if rows else np.zeros(0, COMMAND_ROW_DTYPE)


def _f32_bits(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    return np.where(np.isnan(a), np.uint32(0x7FC00000), a.view(np.uint32))


def merge_symbol_attitude(tel: Telemetry, rows: np.ndarray | None) -> Telemetry:
    """A capture's symbol rows S in ``tel``: the attitude when it has no frames (``source["attitude_from"]``), else
    checked against the frames bit for bit (``source["symbols"]``)."""
    if rows is None or len(rows) == 0:
        return tel
    rows = np.asarray(rows, dtype=SYMBOL_DTYPE)
    t_s = rows["t_s"].astype(np.float64)  # emulated s since power-up, as firmware and host time
    args = (rows["step"], t_s, t_s.copy(), rows["acc_mg"], rows["gyro_mdps"], rows["euler_rad"])
    read = AttitudeArrays.of(*args, thr=rows["thr"], q_wxyz=rows["q_wxyz"], exact=True)
    if len(tel.attitude) == 0:
        tel.attitude = read
        tel.source["attitude_from"] = "symbols"
        tel.source["symbols"] = (
            f"no attitude frames: the attitude of {len(read)} AHRS steps as the emulator read it from the "
            "firmware's globals by symbol (acc_ahrs, gyro_ahrs, gTHR, ahrs, euler_ahrs), not frames it sent"
        )
        return tel
    a = tel.attitude
    frames = np.flatnonzero(np.asarray(a.exact, bool))
    common, fi, ri = np.intersect1d(np.asarray(a.step)[frames], read.step, return_indices=True)
    fi = frames[fi]
    tel.source["attitude_from"] = "frames"
    if common.size == 0:  # text-mode frames (rounded) or no step in common: nothing to compare bit for bit
        tel.source["symbols"] = (
            f"the emulator also read the attitude of {len(read)} AHRS steps by symbol (chunks S); no binary frame "
            "shares a step with them, so they are not compared bit for bit"
        )
        return tel
    fields = ("acc_mg", "gyro_mdps", "q_wxyz", "thx_rad", "thy_rad")
    same = np.ones(common.size, dtype=bool)
    for name in fields:
        x, y = _f32_bits(getattr(a, name)[fi]), _f32_bits(getattr(read, name)[ri])
        same &= (x == y).reshape(common.size, -1).all(axis=1)
    same &= np.asarray(a.thr)[fi] == read.thr[ri]
    if same.all():
        tel.source["symbols"] = (
            f"the emulator also read the attitude by symbol: the frames agree with it bit for bit on all "
            f"{common.size} steps both have"
        )
    else:
        first = int(common[np.argmax(~same)])
        tel.source["symbols"] = (
            f"the emulator also read the attitude by symbol: the frames differ from it on {int((~same).sum())} of "
            f"{common.size} steps (first at step {first}): the frames do not carry the filter's globals"
        )
    return tel
