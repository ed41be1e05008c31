"""``steval export``: a capture as CSV / Parquet (one row per attitude frame, units in column names) or raw bytes."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from steval_link.analysis.ble import load_ble
from steval_link.cli.app import app
from steval_link.cli.checks import require_attitude
from steval_link.cli.outputs import atomic_output, check_output
from steval_link.cli.progress import progress_bar, scaled
from steval_link.errors import UserError
from steval_link.link.ble_payloads import is_ble_source
from steval_link.link.capture import read_source, telemetry_of_source

__all__ = ["write_csv", "write_parquet", "write_raw"]


#: Angle columns of the attitude table and their names in degrees (``--degrees``).
ANGLE_COLUMNS = {"thx_pitch_rad": "thx_pitch_deg", "thy_roll_rad": "thy_roll_deg", "thz_yaw_rad": "thz_yaw_deg",
                 "target_thx_pitch_rad": "target_thx_pitch_deg", "target_thy_roll_rad": "target_thy_roll_deg",
                 "target_thz_yaw_rad": "target_thz_yaw_deg"}


def _column_strings(col: np.ndarray) -> list[str]:
    """Text of one column: integers as such; float32 as the shortest decimal that reads back as the same float32
    (999.4, not 999.400024); float64 times with µs resolution; booleans as 0/1; NaN as an empty field."""
    if col.dtype == bool:
        return ["1" if v else "0" for v in col.tolist()]
    if np.issubdtype(col.dtype, np.integer):
        return [str(v) for v in col.tolist()]
    if col.dtype == np.float32:
        return ["" if v != v else str(v) for v in col]  # numpy's shortest round-trip text of each float32
    return ["" if v != v else "%.6f" % v for v in col.tolist()]


def in_degrees(table: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The table with its angle columns (``*_rad``) in degrees (``*_deg``, float32 like the firmware's angles)."""
    return {
        ANGLE_COLUMNS.get(k, k): np.degrees(np.asarray(v, np.float64)).astype(np.float32) if k in ANGLE_COLUMNS else v
        for k, v in table.items()
    }


def write_csv(table: dict[str, np.ndarray], path: Path, progress=None) -> None:
    """Write a column table as CSV (comma separated, header row, ``\\n`` line endings, UTF-8);
    ``progress(fraction, stage)`` hears of each column formatted."""
    cols = []
    for i, c in enumerate(table.values()):
        if progress is not None:
            progress(i / len(table), "formatting")
        cols.append(_column_strings(np.asarray(c)))
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


def write_raw(data: bytes, path: Path) -> None:
    """Write the exact serial bytes."""
    path.write_bytes(data)


@app.command()
def export(
    capture: Annotated[Path, typer.Argument(help="Capture (.stv), raw serial dump or text-mode log.")],
    csv: Annotated[Optional[Path], typer.Option("--csv", help="Write attitude rows as CSV (Excel, MATLAB).")] = None,
    parquet: Annotated[
        Optional[Path], typer.Option("--parquet", help="Write attitude rows as Parquet (pandas; needs pyarrow).")
    ] = None,
    raw: Annotated[
        Optional[Path], typer.Option("--raw", help="Write the exact serial bytes as received (e.g. OUT.bin).")
    ] = None,
    degrees: Annotated[bool, typer.Option(
        "--degrees", help="Angles in degrees: thx_pitch_deg, thy_roll_deg, thz_yaw_deg instead of the _rad columns."
    )] = False,
    force: Annotated[bool, typer.Option("--force", "-f", help="Overwrite existing output files.")] = False,
) -> None:
    """Export a capture as CSV / Parquet (one row per attitude frame) or as the raw serial bytes.

    Columns, units in the names: step, seq, t_fw_s, t_host_s, acc_x_mg .. acc_z_mg, gyro_x_mdps .. gyro_z_mdps,
    q_w .. q_z, thx_pitch_rad (about x), thy_roll_rad (about y), thz_yaw_rad (_deg with --degrees), thr, exact
    (0 for rounded text-mode rows), offset (stream byte). A capture with flight-control frames adds, on the rows of
    their steps: target_thx_pitch_rad .. target_thz_yaw_rad (the remote's targets), rc_ail, rc_ele, rc_rud, rc_thr,
    outer_s1_x_pitch_radps .. (outer loop outputs), inner_s2_x_pitch_pwm .. (inner loop outputs), motor1_pwm ..
    motor4_pwm (TIM4 counts of 2000), vbat_v, fc_armed, fc_rc_connected, fc_rc_cal, fc_every. Missing values (NaN)
    are empty CSV fields; each float32 value is written as the shortest decimal that reads back as the same float32
    (999.4).

    A BLE capture (steval live --ble) gives one row per motion notification: t_host_s, tick (8 ms, unwrapped),
    t_fw_s, acc_x_mg .. acc_z_mg, gyro_x_mdps .. gyro_z_mdps, mag_x_mgauss .. mag_z_mgauss, and the last
    pressure_hpa, battery_pct, temperature_c, rssi_dbm, armed received before it.
    """
    outputs = [(opt, p) for opt, p in (("--csv", csv), ("--parquet", parquet), ("--raw", raw)) if p is not None]
    if not outputs:
        raise UserError("nothing to export: give --csv OUT, --parquet OUT and/or --raw OUT.bin.")
    src = read_source(capture)  # the input first, then the outputs, then the work
    for opt, p in outputs:
        check_output(p, option=opt, force=force, inputs=(capture,))
    with progress_bar("export") as progress:
        progress(0.1, "decoding")
        if is_ble_source(src):
            _export_ble(src, csv, parquet, raw, progress)
            return
        tel = telemetry_of_source(src) if (csv or parquet) else None
        if tel is not None:
            require_attitude(tel, "export (--raw gives the bytes)")
        for w in src.warnings:  # damaged but with frames: one line of our own, the export goes on
            typer.echo(f"steval: warning: {w}", err=True)
        if raw is not None:
            with atomic_output(raw, option="--raw") as part:
                write_raw(src.data, part)
            typer.echo(f"{raw}: {len(src.data)} bytes")
        if tel is not None:
            table = tel.attitude_table()
            table.update(tel.flight_columns())
            if degrees:
                table = in_degrees(table)
            _write_table(table, csv, parquet, progress, f"{len(tel.attitude)} attitude rows")


def _export_ble(src, csv: Path | None, parquet: Path | None, raw: Path | None, progress) -> None:
    """A BLE capture: one row per motion notification (env and arming values held from their last one)."""
    if raw is not None:
        raise UserError(f"{src.path} is a BLE capture: it has notifications, no serial bytes for --raw "
                        "(use --csv or --parquet).")
    for w in src.warnings:
        typer.echo(f"steval: warning: {w}", err=True)
    ble = load_ble(src)
    _write_table(ble.motion_table(), csv, parquet, progress, f"{len(ble)} motion rows (BLE)")


def _write_table(table, csv: Path | None, parquet: Path | None, progress, rows: str) -> None:
    """The table to the CSV and/or Parquet file asked for, a line each saying how many ``rows``."""
    if csv is not None:
        with atomic_output(csv, option="--csv") as part:
            write_csv(table, part, scaled(progress, 0.3, 0.9 if parquet is not None else 1.0))
        typer.echo(f"{csv}: {rows}")
    if parquet is not None:
        progress(0.9, f"writing {parquet.name}")
        with atomic_output(parquet, option="--parquet") as part:
            write_parquet(table, part)
        typer.echo(f"{parquet}: {rows}")
