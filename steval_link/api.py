"""The Python API for notebooks and scripts: ``import steval_link as sl``.

::

    cap = sl.open_capture("recordings/demo.stv")       # any capture, raw dump or text-mode log
    cap.attitude.t_fw_s, cap.attitude.thx_rad           # numpy arrays, units in the names (pitch = thx, about x)
    est = sl.run_estimator("ekf3", cap)                 # or "my_ekf.py:MyEkf(q_gyro=1e-5)", or MyEkf()
    scores = sl.evaluate("../shared/datasets/broad", ["st-mahony-flight", "vqf", MyEkf()])

``import steval_link`` stays cheap: this module loads on the first use of one of these names.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from steval_link.analysis import evaluate as ev
from steval_link.errors import UserError
from steval_link.estimators import plugins, registry
from steval_link.estimators.base import AttitudeEstimate, Estimator
from steval_link.estimators.runner import run_estimator as _run_named
from steval_link.link.load import read_recording, telemetry_of_recording

__all__ = ["Capture", "Scores", "open_capture", "run_estimator", "evaluate", "require_pandas"]


def require_pandas():
    """The pandas module, or ImportError with the install hint."""
    try:
        import pandas  # optional: only to_pandas() needs it
    except ImportError:
        raise ImportError(
            'to_pandas() needs pandas, which is not installed: pip install pandas (or "steval-link[pandas]")'
        ) from None
    return pandas


@dataclass
class Capture:
    """A decoded capture. ``attitude``: one row per attitude frame (``step``, ``t_fw_s``, ``t_host_s``, ``acc_mg``
    (N, 3), ``gyro_mdps`` (N, 3), ``thr``, ``q_wxyz`` (N, 4), ``thx_rad`` (pitch, about x), ``thy_rad`` (roll,
    about y), ``thz_rad``, ``exact``); ``status`` and ``fc`` the status and flight-control frames; ``telemetry``
    everything (:class:`steval_link.link.telemetry.Telemetry`); ``warnings`` what was odd about the file."""

    path: Path
    telemetry: Any
    warnings: list[str] = field(default_factory=list)

    @property
    def attitude(self):
        return self.telemetry.attitude

    @property
    def status(self):
        return self.telemetry.status

    @property
    def fc(self):
        return self.telemetry.fc

    @property
    def text_series(self):
        """The records of text telemetry (a log of any printf): ``names``, ``units``, ``values`` (N, M),
        ``t_s``, ``column(name)``, ``table()`` (:class:`steval_link.link.text_series.TextSeries`)."""
        return self.telemetry.text_series

    def __len__(self) -> int:
        return len(self.telemetry.attitude)

    def to_pandas(self, *, flight: bool = True):
        """A pandas DataFrame, one row per attitude frame, the columns of ``steval export`` (``t_fw_s``,
        ``acc_x_mg`` .. ``gyro_z_mdps``, ``q_w`` .. ``q_z``, ``thx_pitch_rad``, ``thy_roll_rad``, ...; with
        ``flight`` the flight-control columns too). ImportError with the install hint without pandas."""
        pd = require_pandas()  # before the work: the install hint at once
        table = self.telemetry.attitude_table()
        return pd.DataFrame(table | self.telemetry.flight_columns() if flight else table)

    def __repr__(self) -> str:
        return f"<Capture {self.path.name}: {len(self)} attitude frames, {len(self.status)} status frames>"


def open_capture(path) -> Capture:
    """Read and decode a capture (``.stv``), raw serial dump or text-mode log (UserError for a missing or
    unreadable file, or one without frames)."""
    src = read_recording(path)
    return Capture(Path(path), telemetry_of_recording(src), list(src.warnings))


def _instance_reference(est) -> plugins.Selected:
    """Your estimator object as a reference: each run gets a fresh copy (reset), wrapped in the guard."""
    if lacks := plugins.missing_methods(est):
        raise TypeError(f"{type(est).__name__} is not an estimator: it has {lacks}")
    name = getattr(est, "name", None)
    if not isinstance(name, str) or name == Estimator.name or not name:
        name = type(est).__name__
    ref = plugins.Reference(repr(est), "object", type(est).__name__)
    return plugins.Selected(name, ref, lambda: copy.deepcopy(est), type(est).__name__)


def run_estimator(estimator, data) -> AttitudeEstimate:
    """Run an estimator from power-up over a capture's attitude rows.

    Args:
        estimator: a registry name (``"ekf3"``, ``"st-mahony"``...), a reference (``"my_ekf.py:MyEkf(q=1e-5)"``)
            or an estimator object (anything with ``reset()`` and ``step()``; a copy is run, reset first, so the
            object itself is left as it was).
        data: a :class:`Capture` (:func:`open_capture`), a path to one, or a ``Telemetry``.

    Returns:
        An :class:`~steval_link.estimators.base.AttitudeEstimate`, one row per attitude frame (``q_wxyz``,
        ``thx_rad``, ``thy_rad``, ``thz_rad``, ``valid``). A user's estimator that raises gives
        :class:`~steval_link.estimators.plugins.PluginError` (its file and line; ``details``: the traceback).
    """
    if isinstance(data, (str, Path)):
        data = open_capture(data)
    tel = data.telemetry if isinstance(data, Capture) else data
    if not isinstance(estimator, str):
        est = registry.create(_instance_reference(estimator))  # a fresh copy, guarded
        est.reset()
        return est.run(tel.attitude.acc_mg, tel.attitude.gyro_mdps, tel.attitude.thr)
    out, why = _run_named(estimator if estimator in registry.ESTIMATORS else registry.resolve(estimator), tel)
    if out is None:
        raise UserError(f"estimator {estimator!r} is {why}")
    return out


@dataclass
class Scores:
    """Inclination RMSE against ground truth (degrees) per trial and estimator, and their means.

    ``rmse_deg``: trial → label → RMSE; ``mean_rmse_deg``: label → mean over the trials (None for an incomplete
    estimator); ``scored_fraction``: trial → label → the share of the scored rows its score covers, with
    ``diverged_at_step`` where it stopped for good; ``incomplete``: the labels below 1 somewhere; ``results``: the
    :class:`steval_link.analysis.evaluate.TrialResult` of each trial (``t_s``, ``err_rad`` label → error per step,
    for plots); ``table()`` the text table of ``steval evaluate``; ``to_pandas()`` one row per trial.
    """

    results: list
    summary: dict

    @property
    def rmse_deg(self) -> dict[str, dict[str, float | None]]:
        return self._per_trial("rmse_deg")

    @property
    def mean_rmse_deg(self) -> dict[str, float | None]:
        return dict(self.summary["mean_rmse_deg"])

    @property
    def scored_fraction(self) -> dict[str, dict[str, float | None]]:
        return self._per_trial("scored_fraction")

    @property
    def diverged_at_step(self) -> dict[str, dict[str, int | None]]:
        return self._per_trial("diverged_at_step")

    @property
    def incomplete(self) -> list[str]:
        return list(self.summary["incomplete"])

    def _per_trial(self, key: str) -> dict:
        """trial → label → the summary's ``key`` (a copy)."""
        return {t["trial"]: dict(t[key]) for t in self.summary["trials"]}

    def table(self) -> str:
        return ev.format_table(self.results)

    def to_pandas(self):
        return require_pandas().DataFrame.from_dict(self.rmse_deg, orient="index")

    def __repr__(self) -> str:
        return self.table()


def evaluate(
    trials,
    estimators: Sequence | None = None,
    *,
    own_rate: bool = False,
    seed: int = 0,
    sensor_noise: bool = False,
    max_seconds: float | None = None,
    firmware: Sequence = (),
    variant: str | None = None,
) -> Scores:
    """Score estimators against ground truth: the flow of ``steval evaluate``
    (:func:`steval_link.analysis.evaluate.evaluate_data`).

    Args:
        trials: a BROAD ``.npz`` trial, a capture with ground truth, a directory of trials, or a list of those.
        estimators: labels of ``steval evaluate`` (``st-mahony-flight``, ``st-mahony-ground``, ``accel``,
            ``ekf3``, ``mekf``, ``vqf``), references (``"my_ekf.py:MyEkf"``) and estimator objects, in any mix;
            None: every built-in available.
        own_rate: run at the trial's own 285.7 Hz instead of through the STEVAL sensor pipeline (161.5 Hz).
        seed: seed of the pipeline model (runs are deterministic); ``sensor_noise`` adds the LSM6DSL's noise.
        max_seconds: use only the first seconds of each trial.
        firmware: firmware ELFs to run on the emulated board with each trial and score; ``variant`` the release of
            the replica run on their inputs.
    """
    items = [trials] if isinstance(trials, (str, Path)) else list(trials)
    if estimators is not None and not isinstance(estimators, str):
        listed = list(estimators) if isinstance(estimators, Iterable) else [estimators]
        estimators = [e if isinstance(e, str) else _object_selected(e) for e in listed]
    results = ev.evaluate_data(
        items,
        estimators,
        own_rate=own_rate,
        seed=seed,
        sensor_noise=sensor_noise,
        max_seconds=max_seconds,
        firmware=firmware,
        variant=variant,
    )
    return Scores(results, ev.summary(results))


def _object_selected(est) -> plugins.Selected:
    """An estimator object labelled by its name and its public number, text and flag attributes, as options would
    read (``Gravity(gain=0.5)``), so two variants of one class keep two labels."""
    sel = _instance_reference(est)
    attrs = [
        f"{k}={v!r}"
        for k, v in getattr(est, "__dict__", {}).items()
        if not k.startswith("_") and k != "name" and isinstance(v, (bool, int, float, str))
    ]
    return sel.renamed(f"{sel}({', '.join(attrs[:6])})" if attrs else str(sel))
