"""Checks of command-line values shared by the sub-commands, each a one-line UserError naming the option."""

from __future__ import annotations

import math
import os
import shlex
from collections.abc import Sequence

from steval_link.cli.app import option, with_options
from steval_link.errors import ParamError, UserError
from steval_link.estimators import registry
from steval_link.estimators.st_mahony import variant_name

#: Largest gTHR the firmware can hold (int16; the remote gives 0 .. 255·13).
MAX_THROTTLE = 32767


#: the library parameters whose flag is not ``--`` and the name with dashes
_FLAGS = dict(
    throttle="--throttle-schedule", fmt="--format", duration_s="--duration", join_at_s="--join-at", path="--out"
)


def flag_of(param: str) -> str:
    """The command-line flag of a library parameter (``duration_s`` → ``--duration``)."""
    return _FLAGS.get(param, "--" + param.replace("_", "-"))


def estimator_names(given: list[str] | None, default, **kwargs) -> list[str]:
    """The estimators of a repeatable ``-e`` whose values may be comma-separated lists (``default`` when none)."""
    return registry.parse_names(",".join(given) if given else None, default, **kwargs)


def user_message(exc: Exception) -> str:
    """An error's sentence for a command-line user: a :class:`ParamError` names flags, not parameters."""
    return exc.worded(flag_of) if isinstance(exc, ParamError) else str(exc)


def command_line(words: list[str], settings: dict) -> str:
    """The command line that repeats a run: ``words``, then each setting by its flag (True: the flag alone; False:
    its ``--no-`` form; a list: the flag repeated; None: not given, left out)."""
    parts = list(words)
    for name, value in settings.items():
        if value is None:
            continue
        flag = flag_of(name)
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, bool):
                parts.append(flag if v else "--no-" + flag[2:])
            else:
                parts += [flag, f"{v:g}" if isinstance(v, float) else str(v)]
    return shlex.join(parts)


def _num(value: float) -> str:
    return f"{float(value):g}"


def check_gain(option: str, value: float | None) -> None:
    """A filter gain (kp, KI): a finite number ≥ 0 (None: not given)."""
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise UserError(f"{option} must be a gain ≥ 0, got {_num(value)}")


def check_throttle(option: str, value: int | None) -> None:
    """A firmware throttle gTHR: 0 .. :data:`MAX_THROTTLE` (None: not given)."""
    if value is not None and not 0 <= value <= MAX_THROTTLE:
        raise UserError(
            f"{option} is the firmware's gTHR (int16, from 0; MIN_THR is 200): 0..{MAX_THROTTLE}, got {value}"
        )


# The filter's options, one definition each, shared by every command that runs the replica (None: not given).
KiOption = option(float | None, "--ki", help="The filter's integral gain AHRS_KI (firmware 0.1; lab exercise 4: 1.0).")
KpGroundOption = option(float | None, "--kp-ground", help="The filter's kp below MIN_THR (firmware 10).")
KpFlightOption = option(float | None, "--kp-flight", help="The filter's kp at or above MIN_THR (firmware 0.4).")
MinThrOption = option(int | None, "--min-thr", help="MIN_THR, the gTHR from which kp is the flight one (firmware 200).")
CorrectionOption = option(
    bool | None,
    "--correction/--no-correction",
    help="With or without the accelerometer correction (without: g* = g, lab exercise 5). Default: with.",
)
DtOption = option(
    float | None, "--dt", help="The filter's integration period, s (firmware 0.00625; TIM9 gives ≈ 0.00619)."
)


#: ``--throttle-schedule``: the throttle over time of an emulated or modelled drone (``--throttle`` of ``simulate``
#: is one gTHR value for every step)
ThrottleScheduleOption = option(
    str | None,
    "--throttle-schedule",
    metavar="N|t:v,...",
    help="Override the throttle gTHR: N (constant) or 't:v,t:v,...' (s since power-up : gTHR, linear in between, held "
    "outside).",
)
#: --throttle-schedule's former name, hidden: the header commands of captures made with it still run
ThrottleFormerOption = option(str | None, "--throttle", hidden=True)


#: ``--variant RELEASE``: the one option, shared by every command that runs the replica, forcing a release's filter.
VariantOption = option(
    str | None,
    "--variant",
    metavar="RELEASE",
    help="The ST release whose filter arithmetic the replica reproduces: 170120 (also 170318 and the 301117 beta) or "
    "221117. Default: recognised from the firmware ELF or from the data (the bit-exact one).",
)


def check_variant(value: str | None) -> str | None:
    """``--variant``: the variant's name ("ST 221117"), None when not given; one sentence for an unknown release."""
    if value is None:
        return None
    try:
        return variant_name(value)
    except ValueError as exc:
        raise UserError(f"--variant: {exc}") from None


#: the filter replica's options of compare and conformance, by parameter
_FILTER_OPTIONS = {"ki": KiOption, "kp_ground": KpGroundOption, "kp_flight": KpFlightOption, "dt": DtOption}
_FILTER_OPTIONS |= {"min_thr": MinThrOption, "correction": CorrectionOption, "variant": VariantOption}


def with_filter_options(order: str):
    """The command takes the filter options named in ``order`` in place of its parameter ``filters``, as a dict."""
    return with_options("filters", tuple((name, _FILTER_OPTIONS[name], None) for name in order.split()), dict)


def filter_settings(filters: dict) -> tuple[dict, str | None]:
    """The filter options given, checked (``dt`` as ``dt_s``), and the variant's name (None: not given)."""
    for name in ("ki", "kp_ground", "kp_flight"):
        check_gain(flag_of(name), filters[name])
    check_throttle("--min-thr", filters["min_thr"])
    check_period("--dt", filters["dt"])
    changes = {("dt_s" if k == "dt" else k): v for k, v in filters.items() if v is not None and k != "variant"}
    return changes, check_variant(filters["variant"])


def check_period(option: str, value: float | None) -> None:
    """An integration period: a finite number of seconds > 0 (None: not given)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UserError(f"{option} must be a period > 0 s, got {_num(value)}")


def check_count(option: str, value: int, maximum: int) -> None:
    """A count (iterations, steps): 0 .. ``maximum``."""
    if not 0 <= value <= maximum:
        raise UserError(f"{option} must be between 0 and {maximum:,}".replace(",", " ") + f", got {value}")


def check_vector(option: str, values: Sequence[float], unit: str) -> None:
    """A sensor vector: every component a finite number (no nan, no inf)."""
    if not all(math.isfinite(v) for v in values):
        raise UserError(f"{option} takes finite numbers in {unit}, got {' '.join(_num(v) for v in values)}")


def require_attitude(tel, purpose: str) -> None:
    """A capture without attitude frames (or a BLE one): UserError saying what it holds and what cannot be done."""
    path = tel.source.get("path", "the capture")
    try:
        size = f"{os.path.getsize(path)} bytes, "
    except (OSError, TypeError):
        size = ""
    if getattr(tel, "link", None) is not None:
        raise UserError(
            f"{path}: {size}a BLE capture ({sum(tel.link.counts.values())} notifications, no serial frames): steval "
            f"replay, export and compare A B read it; nothing to {purpose} without serial frames."
        )
    if len(tel.attitude):
        return
    held = (
        f"{len(tel.status)} status frames and {len(tel.text)} text lines"
        if len(tel.status) + len(tel.text)
        else "no frames"
    )
    series = getattr(tel, "text_series", None)
    if series is not None and len(series):  # text telemetry, none of it an attitude
        why = series.notes[0].rstrip(".") if series.notes else "say which is the attitude with --map pitch=SERIES:deg"
        raise UserError(
            f"{path}: {len(series)} text records ({', '.join(series.names)}), none of them an attitude: "
            f"nothing to {purpose} ({why})."
        )
    raise UserError(f"{path}: {size}{held}, no attitude frames: nothing to {purpose}.")
