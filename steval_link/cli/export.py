"""``steval export``: a capture as CSV / Parquet (one row per attitude frame, units in column names) or raw bytes."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from steval_link.capture import read_source, telemetry_of_source
from steval_link.cli.app import app
from steval_link.errors import UserError

__all__ = ["write_csv", "write_parquet", "write_raw"]


def _column_strings(col: np.ndarray) -> list[str]:
    """Text of one column: integers as such, float32 with 9 significant digits (exact round trip), float64 times
    with µs resolution, booleans as 0/1, NaN as an empty field."""
    if col.dtype == bool:
        return ["1" if v else "0" for v in col.tolist()]
    if np.issubdtype(col.dtype, np.integer):
        return [str(v) for v in col.tolist()]
    fmt = "%.9g" if col.dtype == np.float32 else "%.6f"
    return ["" if v != v else fmt % v for v in col.tolist()]


def write_csv(table: dict[str, np.ndarray], path: Path) -> None:
    """Write a column table as CSV (comma separated, header row, ``\\n`` line endings, UTF-8)."""
    cols = [_column_strings(np.asarray(c)) for c in table.values()]
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
    force: Annotated[bool, typer.Option("--force", "-f", help="Overwrite existing output files.")] = False,
) -> None:
    """Export a capture as CSV / Parquet (one row per attitude frame) or as the raw serial bytes.

    Columns, units in the names: step, seq, t_fw_s, t_host_s, acc_x_mg .. acc_z_mg, gyro_x_mdps .. gyro_z_mdps,
    q_w .. q_z, thx_pitch_rad (about x), thy_roll_rad (about y), thz_yaw_rad, thr, exact (0 for rounded text-mode
    rows), offset (stream byte). Missing values (NaN) are empty CSV fields.
    """
    outputs = [(opt, p) for opt, p in (("--csv", csv), ("--parquet", parquet), ("--raw", raw)) if p is not None]
    if not outputs:
        raise UserError("nothing to export: give --csv OUT, --parquet OUT and/or --raw OUT.bin.")
    for opt, p in outputs:
        if p.resolve() == capture.resolve():
            raise UserError(f"{opt} {p} is the capture itself; choose another output file.")
        if p.exists() and not force:
            raise UserError(f"{p} already exists (use --force to overwrite).")
        if not p.parent.is_dir():
            raise UserError(f"{opt} {p}: directory {p.parent} does not exist.")
    src = read_source(capture)
    tel = telemetry_of_source(src) if (csv or parquet) else None
    for w in src.warnings:
        typer.echo(f"steval: warning: {w}", err=True)
    try:
        if raw is not None:
            write_raw(src.data, raw)
            typer.echo(f"{raw}: {len(src.data)} bytes")
        if tel is not None:
            table = tel.attitude_table()
            n = len(tel.attitude)
            if csv is not None:
                write_csv(table, csv)
                typer.echo(f"{csv}: {n} attitude rows")
            if parquet is not None:
                write_parquet(table, parquet)
                typer.echo(f"{parquet}: {n} attitude rows")
    except OSError as exc:
        raise UserError(f"cannot write {exc.filename or 'output'}: {exc.strerror or exc}.") from None
