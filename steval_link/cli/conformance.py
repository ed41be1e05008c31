"""``steval conformance``: the replica against firmware vectors, naming the ST release whose filter computed them."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import typer

from steval_link.analysis.report import json_number
from steval_link.cli.app import app
from steval_link.cli.checks import filter_settings, with_filter_options
from steval_link.cli.outputs import check_input
from steval_link.errors import UserError
from steval_link.estimators.st_mahony import MahonySettings


@app.command("conformance")
@with_filter_options("ki kp_ground kp_flight min_thr dt correction variant")
def conformance_command(
    csv_files: list[Path] = typer.Argument(
        ..., metavar="CSV...", help="Conformance vector files (firmware outputs), or directories of them."
    ),
    json_out: bool = typer.Option(False, "--json", help="Print the per-file results as JSON."),
    filters: dict = None,
    pure: bool = typer.Option(False, "--pure", help="Use the pure-Python loop instead of the compiled one."),
) -> None:
    """Run the bit-exact Mahony replica on each file's inputs and compare every output bit with the firmware's.

    The ST release is named: the filter variant that is bit-exact on every step (or --variant).

    Exit status 0 when every step of every file is bit-exact, 1 otherwise, 2 for unreadable files.
    """
    from steval_link.estimators.conformance import (  # reason: start-up time
        check_conformance,
        variant_scores,
    )

    changes, forced = filter_settings(filters)
    settings = MahonySettings(**changes)  # filter_settings checked each value
    cases = [_load_case(path) for path in _csv_paths(csv_files)]
    native = False if pure else None
    scores = None
    if forced is None:
        scores = variant_scores(cases, settings, native=native)
        forced = max(scores, key=lambda v: scores[v])  # the first of the best: the default on a tie
    settings = replace(settings, variant=forced)
    results = [check_conformance(case, settings, native=native) for case in cases]
    all_ok = all(r.ok for r in results)
    if json_out:
        _print_json(results, settings, scores, all_ok)
    else:
        _print_table(results, all_ok)
        print(_filter_line(settings.variant, scores, sum(r.steps for r in results)))
    if not all_ok:
        raise SystemExit(1)


def _csv_paths(csv_files: list[Path]) -> list[Path]:
    """The files, and each directory's ``*.csv``."""
    paths: list[Path] = []
    for path in csv_files:
        if path.is_dir():
            found = sorted(path.glob("*.csv"))
            if not found:
                raise UserError(f"{path}: directory holds no .csv conformance files")
            paths.extend(found)
        else:
            paths.append(check_input(path, what="conformance file"))
    return paths


def _load_case(path: Path):
    """One conformance file, or one sentence why not."""
    from steval_link.estimators.conformance import load_conformance_csv  # reason: start-up time

    try:
        return load_conformance_csv(path)
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _print_json(results, settings: MahonySettings, scores: dict[str, int] | None, all_ok: bool) -> None:
    out = {
        "filter": settings.variant,
        "filter_from": "--variant" if scores is None else "data",
        "variant_bit_exact_steps": scores,
        "settings": settings.__dict__,
        "ok": all_ok,
        "files": [
            {**r.as_dict(), "max_abs_dq": json_number(r.max_abs_dq), "max_abs_dth_rad": json_number(r.max_abs_dth)}
            for r in results
        ],
    }
    print(json.dumps(out, indent=2))


def _print_table(results, all_ok: bool) -> None:
    width = max(len(r.name) for r in results)
    print(f"{'file':<{width}}  {'steps':>8}  {'bit-exact':>9}  {'max|Δq|':>10}  {'max|Δθ| rad':>11}  first mismatch")
    for r in results:
        first = "-" if r.first_mismatch_step is None else f"step {r.first_mismatch_step}"
        if r.nan_mismatches:
            first += f" ({r.nan_mismatches} NaN on one side only)"
        print(
            f"{r.name:<{width}}  {r.steps:>8}  {r.exact_steps:>9}  {r.max_abs_dq:>10.3g}  "
            f"{r.max_abs_dth:>11.3g}  {first}"
        )
    exact = sum(r.exact_steps for r in results)
    total = sum(r.steps for r in results)
    print(f"{len(results)} file(s), {exact} of {total} steps bit-exact: {'all bit-exact' if all_ok else 'MISMATCH'}")


def _filter_line(variant: str, scores: dict[str, int] | None, total: int) -> str:
    """The line naming the release: forced, recognised (bit-exact) or the closest, with the others' counts."""
    if scores is None:
        return f"filter: {variant} (--variant)"
    others = "; ".join(f"{v}: {n} of {total}" for v, n in scores.items() if v != variant)
    if scores[variant] == total:
        return f"filter: {variant} (recognised: the variant bit-exact on every step; {others})"
    return f"filter: none of ST's releases is bit-exact; closest {variant} ({scores[variant]} of {total}; {others})"
