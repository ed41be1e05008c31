"""``steval export``: a capture as CSV / Parquet (one row per attitude frame, units in column names) or raw bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from steval_link.analysis.frame_tables import frame_tables, header_of, settings_of
from steval_link.analysis.mat_export import require_scipy, write_mat
from steval_link.analysis.mcap_export import require_mcap, write_mcap
from steval_link.cli.app import app, argument, option
from steval_link.cli.checks import require_attitude
from steval_link.cli.outputs import ForceOption, atomic_output, check_outputs, print_warnings, write_atomic
from steval_link.cli.progress import progress_bar, scaled
from steval_link.errors import UserError
from steval_link.link.ble_payloads import is_ble_source
from steval_link.link.load import read_recording, telemetry_of_recording

#: Angle columns of the attitude table and their names in degrees (``--degrees``).
ANGLE_COLUMNS = {f"{p}{a}_rad": f"{p}{a}_deg" for p in ("", "target_") for a in ("thx_pitch", "thy_roll", "thz_yaw")}


def _column_strings(col: np.ndarray, shortest: bool = False) -> list[str]:
    """Text of one column: integers as such; float32 as the shortest decimal that reads back as the same float32
    (999.4, not 999.400024); float64 times with µs resolution (``shortest``: the shortest decimal that reads back,
    as a log printed it); booleans as 0/1; NaN as an empty field."""
    if col.dtype == bool:
        return ["1" if v else "0" for v in col.tolist()]
    if np.issubdtype(col.dtype, np.integer):
        return [str(v) for v in col.tolist()]
    if col.dtype == np.float32:
        return ["" if v != v else str(v) for v in col]  # numpy's shortest round-trip text of each float32
    if shortest:
        return ["" if v != v else str(int(v)) if v.is_integer() and abs(v) < 2**53 else repr(v) for v in col.tolist()]
    return ["" if v != v else "%.6f" % v for v in col.tolist()]


def in_degrees(table: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The table with its angle columns (``*_rad``) in degrees (``*_deg``, float32 like the firmware's angles)."""
    return {
        ANGLE_COLUMNS.get(k, k): np.degrees(np.asarray(v, np.float64)).astype(np.float32) if k in ANGLE_COLUMNS else v
        for k, v in table.items()
    }


def write_csv(table: dict[str, np.ndarray], path: Path, progress=None, shortest: bool = False) -> None:
    """Write a column table as CSV (header row, ``\\n`` line endings, UTF-8); ``shortest``: see ``_column_strings``."""
    cols = []
    for i, c in enumerate(table.values()):
        if progress is not None:
            progress(i / len(table), "formatting")
        cols.append(_column_strings(np.asarray(c), shortest))
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(",".join(table) + "\n")
        f.writelines(",".join(row) + "\n" for row in zip(*cols))


def write_parquet(table: dict[str, np.ndarray], path: Path) -> None:
    """Write a column table as Parquet (needs pyarrow)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise UserError("--parquet needs pyarrow (pip install pyarrow); --csv works without it.") from None
    pq.write_table(pa.table({k: np.asarray(v) for k, v in table.items()}), str(path))


_Degrees = option(
    bool, "--degrees", help="Angles in degrees: thx_pitch_deg, thy_roll_deg, thz_yaw_deg instead of the _rad columns."
)


@app.command()
def export(
    capture: argument(Path, help="Capture (.stv), raw serial dump or text-mode log."),
    csv: option(Path | None, help="Write attitude rows (a text log: a row per record) as CSV (Excel, MATLAB).") = None,
    parquet: option(Path | None, help="Write attitude rows as Parquet (pandas; needs pyarrow).") = None,
    raw: option(Path | None, help="Write the exact serial bytes as received (e.g. OUT.bin).") = None,
    mat: option(
        Path | None,
        help="Write a MATLAB file: one struct per frame type (attitude, status, fc, ...) with the CSV's columns, plus "
        "settings and header (needs scipy).",
    ) = None,
    mcap: option(
        Path | None,
        help="Write an MCAP file (Foxglove, PlotJuggler, ROS 2, Rerun): attitude as foxglove.FrameTransform and "
        "PoseInFrame, steval.Attitude, steval.Status, steval.FlightControl, JSON, on the firmware clock (needs mcap).",
    ) = None,
    degrees: _Degrees = False,
    force: ForceOption = False,
) -> None:
    """Export a capture as CSV / Parquet (one row per attitude frame), MATLAB (--mat), MCAP (--mcap) or as the raw
    serial bytes.

    Columns, units in the names: step, seq, t_fw_s, t_host_s, acc_x_mg .. acc_z_mg, gyro_x_mdps .. gyro_z_mdps,
    q_w .. q_z, thx_pitch_rad (about x), thy_roll_rad (about y), thz_yaw_rad (_deg with --degrees), thr, exact
    (0 for rounded text-mode rows), offset (stream byte), values_bad (1: NaN or out-of-range values as the firmware
    sent them, e.g. its filter diverged). A capture with flight-control frames adds, on the rows of
    their steps: target_thx_pitch_rad .. target_thz_yaw_rad (the remote's targets), rc_ail, rc_ele, rc_rud, rc_thr,
    outer_s1_x_pitch_radps .. (outer loop outputs), inner_s2_x_pitch_pwm .. (inner loop outputs), motor1_pwm ..
    motor4_pwm (TIM4 counts of 2000), vbat_v, fc_armed, fc_rc_connected, fc_rc_cal, fc_every. Missing values (NaN)
    are empty CSV fields; each float32 value is written as the shortest decimal that reads back as the same float32
    (999.4).

    A BLE capture (steval live --ble) gives one row per motion notification: t_host_s, tick (8 ms, unwrapped),
    t_fw_s, acc_x_mg .. acc_z_mg, gyro_x_mdps .. gyro_z_mdps, mag_x_mgauss .. mag_z_mgauss, and the last
    pressure_hpa, battery_pct, temperature_c, rssi_dbm, armed received before it.

    --mat: structs attitude (the columns above), status, fc (one row per flight-control frame), ack, command, text
    (those the capture holds), settings and header; load('OUT.mat') in MATLAB. --mcap: topics /attitude/transform
    (foxglove.FrameTransform), /attitude/pose (foxglove.PoseInFrame), /attitude (steval.Attitude), /status,
    /flight_control; JSON, log time = firmware time. Both are written to OUT.partial, then renamed.
    """
    outputs = {"--csv": csv, "--parquet": parquet, "--raw": raw, "--mat": mat, "--mcap": mcap}
    if not any(outputs.values()):
        raise UserError(
            "nothing to export: give --csv OUT, --parquet OUT, --raw OUT.bin, --mat OUT.mat and/or --mcap OUT.mcap."
        )
    if mat is not None:
        require_scipy()  # before any work: one line when scipy is missing
    if mcap is not None:
        require_mcap()
    src = read_recording(capture)  # the input first, then the outputs, then the work
    check_outputs(outputs, force=force, inputs=(capture,))
    with progress_bar("export") as progress:
        progress(0.1, "decoding")
        if is_ble_source(src):
            _export_ble(telemetry_of_recording(src), outputs, progress)
        else:
            _export_serial(src, outputs, degrees, progress)


def _export_serial(src, outputs: dict, degrees: bool, progress) -> None:
    """A serial capture or text log: its attitude rows (a text log's records), the bytes, MATLAB and MCAP."""
    csv, parquet, raw, mat, mcap = outputs.values()
    tel = telemetry_of_recording(src) if (csv or parquet or mat or mcap) else None
    records = tel is not None and tel.printed_only
    if tel is not None and not (records and mcap is None):
        require_attitude(tel, "export (--raw gives the bytes)")
    print_warnings(src.warnings)  # damaged but with frames: the export goes on
    if raw is not None:
        write_atomic(raw, "--raw", lambda f: f.write(src.data))
        typer.echo(f"{raw}: {len(src.data)} bytes")
    if records and (csv is not None or parquet is not None):  # a text log: a row per record
        rows = f"{len(tel.text_series)} text records"
        _write_table(tel.text_series.table(), csv, parquet, progress, rows, shortest=True)
    elif csv is not None or parquet is not None:
        table = tel.attitude_table() | tel.flight_columns()
        _write_table(
            in_degrees(table) if degrees else table, csv, parquet, progress, f"{len(tel.attitude)} attitude rows"
        )
    if mat is not None:
        _export_mat(tel, mat, degrees, progress)
    if mcap is not None:
        _export_mcap(tel, mcap, progress)


def _export_mat(tel, path: Path, degrees: bool, progress) -> None:
    """One struct per frame type (the CSV's columns), settings and header, as a MATLAB file."""
    progress(0.5, f"writing {path.name}")
    tables = frame_tables(tel)
    if degrees:
        tables = {k: in_degrees(t) for k, t in tables.items()}
    write_atomic(path, "--mat", lambda f: write_mat(tables, settings_of(tel), header_of(tel), f))
    counts = ", ".join(f"{len(next(iter(t.values())))} {k}" for k, t in tables.items() if t)
    typer.echo(f"{path}: MATLAB structs {', '.join(tables)} (rows: {counts}), settings, header")


def _export_mcap(tel, path: Path, progress) -> None:
    """The capture as MCAP (topics and schemas: steval_link.analysis.mcap_export)."""
    counts: dict[str, int] = {}
    meta = {"settings": settings_of(tel), "header": header_of(tel)}
    write_atomic(
        path, "--mcap", lambda f: counts.update(write_mcap(tel, f, metadata=meta, progress=scaled(progress, 0.5, 1.0)))
    )
    typer.echo(f"{path}: MCAP, " + ", ".join(f"{topic} {n}" for topic, n in counts.items()))


def _export_ble(tel, outputs: dict, progress) -> None:
    """A BLE capture: one row per motion sample received (env and arming values held from their last one)."""
    csv, parquet, raw, mat, mcap = outputs.values()
    path = tel.source["path"]
    if raw is not None or mcap is not None:
        raise UserError(
            f"{path} is a BLE capture: it has notifications, no serial bytes for --raw or attitude frames for --mcap "
            "(use --csv, --parquet or --mat)."
        )
    print_warnings(tel.source["warnings"])
    table, n = tel.link.motion_table(), len(tel.link.samples)
    _write_table(table, csv, parquet, progress, f"{n} motion rows (BLE)")
    if mat is not None:
        header = dict(tel.source["header"] or {}, path=str(path), kind="ble")
        write_atomic(mat, "--mat", lambda f: write_mat({"motion": table}, {"from": "none"}, header, f))
        typer.echo(f"{mat}: MATLAB struct motion ({n} rows, BLE), settings, header")


def _write_table(table, csv: Path | None, parquet: Path | None, progress, rows: str, shortest: bool = False) -> None:
    """The table to the CSV and/or Parquet file asked for, a line each saying how many ``rows``."""
    if csv is not None:
        with atomic_output(csv, option="--csv") as part:
            write_csv(table, part, scaled(progress, 0.3, 0.9 if parquet is not None else 1.0), shortest)
        typer.echo(f"{csv}: {rows}")
    if parquet is not None:
        progress(0.9, f"writing {parquet.name}")
        with atomic_output(parquet, option="--parquet") as part:
            write_parquet(table, part)
        typer.echo(f"{parquet}: {rows}")
