"""``steval estimator new`` (a working 3-state EKF to start from) and ``steval estimator check`` (checks, scores)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import typer

from steval_link.cli.app import argument, option, sub_app
from steval_link.cli.data import find_broad_data
from steval_link.cli.outputs import ForceOption, JsonReportOption, atomic_output, check_output, print_json
from steval_link.cli.progress import progress_bar
from steval_link.emulation import broad
from steval_link.errors import UserError

estimator_app = sub_app(
    "estimator", "Your own estimator: write a starter (new), check it and score it (check). See docs/ESTIMATORS.md."
)

#: the class name in the starter file
STARTER_CLASS = "MyEkf"
#: where ``check`` looks for BROAD trials when no ``--broad`` is given (the course's shared data beside the clone)
DEFAULT_BROAD = Path("../shared/datasets/broad")
_CLASS_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def starter_source(class_name: str = STARTER_CLASS) -> str:
    """The starter's Python source (``steval_link/estimators/starter_ekf.py``) with its class named ``class_name``."""
    path = Path(__file__).resolve().parents[1] / "estimators" / "starter_ekf.py"
    return re.sub(rf"\b{STARTER_CLASS}\b", class_name, path.read_text(encoding="utf-8"))


@estimator_app.command("new")
def new_command(
    file: argument(Path, help="The Python file to write, e.g. my_ekf.py."),
    class_name: option(str, "--class", help="Name of the estimator class in it.") = STARTER_CLASS,
    force: ForceOption = False,
) -> None:
    """Write a starter estimator that works as it is: a 3-state EKF (Euler angles; prediction from the gyro,
    update from the accelerometer), the lecture's steps marked, its tuning knobs named (q_gyro, r_acc, p0)."""
    if file.suffix != ".py":
        raise UserError(f"{file}: the starter is Python; give a name ending in .py (e.g. my_ekf.py)")
    if not _CLASS_NAME.fullmatch(class_name):
        raise UserError(f"--class {class_name!r} is not a Python class name")
    check_output(file, option="", force=force)
    with atomic_output(file, option="", keep_suffix=True) as part:
        part.write_text(starter_source(class_name), encoding="utf-8")
    ref = f"{file}:{class_name}"
    print(f"wrote {file}: class {class_name}, a 3-state EKF (gyro prediction, accelerometer update)")
    print("next:")
    print(f"  steval estimator check {ref}")
    print(f"  steval compare recordings/demo.stv -e {ref}")


@estimator_app.command("check")
def check_command(
    estimator: argument(
        str,
        help="FILE.py:CLASS (or module:CLASS, an installed plug-in, a built-in), options in parentheses: "
        "'my_ekf.py:MyEkf(q_gyro=1e-5)'.",
    ),
    broad_path: option(
        list[Path] | None,
        "--broad",
        help="BROAD trials (.npz) or directories of them to score on (repeatable). Default: "
        f"{DEFAULT_BROAD} when it exists.",
    ) = None,
    no_broad: option(bool, "--no-broad", help="Do not score on BROAD trials (quicker).") = False,
    as_json: JsonReportOption = False,
) -> None:
    """Check an estimator's interface (shapes, units and signs at rest and tilted, a turn, NaN and invalid input,
    determinism, steps per second), then score it next to ST-Mahony, the built-in EKF and VQF: tilt difference
    from the firmware and from accelerometer-only tilt on the bundled captures, inclination RMSE against ground
    truth on BROAD trials. Exit 1 when a check fails."""
    from steval_link.analysis.estimator_check import format_check, run_check  # reason: start-up time

    folders = [] if no_broad else broad_path or ([DEFAULT_BROAD] if DEFAULT_BROAD.is_dir() else [])
    if not (no_broad or folders) and (cached := find_broad_data()) is not None:  # the trials of steval data broad
        folders = [cached]
    with progress_bar("estimator check", quiet=as_json) as progress:
        report = run_check(estimator, broad_paths=broad.trial_paths(folders) if folders else [], progress=progress)
    if not (no_broad or folders or report.broad_note):
        report.broad_note = "no BROAD trials (steval data broad downloads them; --broad PATH scores on others)"
    if as_json:
        print_json(report.as_dict() | ({"traceback": report.traceback} if report.traceback else {}))
    else:
        if report.traceback:
            print(report.traceback, file=sys.stderr)
        print("\n".join(format_check(report)))
    if not report.ok:
        raise typer.Exit(1)
