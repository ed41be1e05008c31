"""The bit-exact ST-Mahony replica against the firmware (:func:`compare_replica`): the steps that match bit for bit,
the first that differs and *why*: the replica re-run from the same seed with other settings (release, KI, correction,
kp, dt, MIN_THR and pairs of them) names the one that reproduces the firmware. A firmware whose own filter diverged
(:func:`find_divergence`) is named with the step and its inputs; replica finite there: its ``ahrs.c`` differs."""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import combinations
from types import SimpleNamespace
from typing import Any

import numpy as np

from steval_link import constants as C
from steval_link.analysis.link_stats import relative_time_s
from steval_link.analysis.report import ReplicaComparison, json_number, setting_text
from steval_link.estimators.firmware_replay import FirmwareReplay, release_sentence, replay_firmware, replay_variants
from steval_link.estimators.st_mahony import VARIANTS, MahonySettings, MahonyState, bits_equal
from steval_link.estimators.st_mahony import run as mahony_run
from steval_link.link.plausibility import q_off_sphere
from steval_link.link.protocol import FLAG_EVENT

#: Rows after the first mismatch over which an alternative setting must reproduce the firmware to be named.
DIAGNOSIS_WINDOW_ROWS = 600


_DT_REAL_S = float(np.float32(1.0 / 161.5))
_KP_DEFAULTS = (C.KP_GROUND, C.KP_FLIGHT)
_FLOAT_SETTINGS = ("kp_ground", "kp_flight", "ki", "dt_s")


def _settings_dict(s: MahonySettings) -> dict[str, Any]:
    floats = {k: float(np.float32(getattr(s, k))) for k in _FLOAT_SETTINGS}
    return floats | {k: getattr(s, k) for k in ("min_thr", "correction", "variant")}


def _same_settings(a: MahonySettings, b: MahonySettings) -> bool:
    return _settings_dict(a) == _settings_dict(b)


def _pick(table, rows: np.ndarray, keys: tuple[str, ...]) -> SimpleNamespace:
    """Columns ``keys`` of a frame table at ``rows``."""
    return SimpleNamespace(**{k: np.asarray(getattr(table, k))[rows] for k in keys})


def filter_settings_report(tel) -> dict[str, Any] | None:
    """The filter settings the status frames report against the 170120 defaults (text mode: ki, flags), or None."""
    s = tel.status
    ex = np.asarray(s.exact, bool) if len(s) else np.zeros(0, bool)
    if len(s) and not ex.any():
        ki = float(s.ki[-1])
        return {
            "from": "text-mode status lines",
            "ki": json_number(ki),
            "flags": int(s.flags[-1]),
            "differs_from_defaults": {}
            if not math.isfinite(ki) or np.float32(ki) == np.float32(C.KI)
            else {"ki": [json_number(ki), C.KI]},
            "changes": 0,
        }
    # a snapshot holding NaN (a diverged filter) still reports the build's settings; non-finite settings do not
    for k in _FLOAT_SETTINGS:
        ex = ex & np.isfinite(np.asarray(getattr(s, k), np.float64))
    if not ex.any():
        return None
    rows = np.flatnonzero(ex)
    picked = _pick(s, rows, ("kp_ground", "kp_flight", "ki", "dt_s", "min_thr", "flags"))
    settings = [MahonySettings.of_status(picked, j) for j in range(rows.size)]
    d = _settings_dict(settings[-1])
    defaults = _settings_dict(MahonySettings())
    changes = sum(1 for x, y in zip(settings[:-1], settings[1:]) if not _same_settings(x, y))
    return {
        "from": "status frames",
        "status_frames": int(rows.size),
        **d,
        "flags": int(s.flags[rows[-1]]),
        "differs_from_defaults": {k: [d[k], defaults[k]] for k in d if d[k] != defaults[k]},
        "changes": changes,
        "change_list": _change_list(s, rows, settings),
    }


def _change_list(s, rows: np.ndarray, settings: list[MahonySettings]) -> list[dict[str, Any]]:
    """Each change the status frames show, in stream order: ``{"step": the first step it applies to, "status_row",
    "event": announced at once after a host command (flag EVENT), "text": "ki 0.1 → 1, correction on → off" or
    "filter reset"}``. A reset is an EVENT status whose parameter generation moved on with the same settings."""
    flags = np.asarray(s.flags)[rows].astype(np.int64)
    steps = np.asarray(s.step)[rows].astype(np.int64)
    gen = np.asarray(getattr(s, "param_gen", np.zeros(len(s.flags))))[rows].astype(np.int64)
    out = []
    for i in range(1, len(settings)):
        a, b = _settings_dict(settings[i - 1]), _settings_dict(settings[i])
        parts = [f"{k} {setting_text(a[k])} → {setting_text(b[k])}" for k in a if a[k] != b[k]]
        if not parts and gen[i] != gen[i - 1] and flags[i] & FLAG_EVENT:
            parts = ["filter reset (q = 1, 0, 0, 0; integrals 0)"]
        if parts:
            out.append(
                {
                    "step": int(steps[i]) + 1,
                    "status_row": int(rows[i]),
                    "event": bool(flags[i] & FLAG_EVENT),
                    "text": ", ".join(parts),
                }
            )
    return out


def _binary_view(tel):
    """Attitude and status rows of binary frames only (what the replica can be compared with bit for bit)."""
    a, s = tel.attitude, tel.status
    rows = np.flatnonzero(np.asarray(a.exact, bool))
    srows = np.flatnonzero(np.asarray(s.exact, bool)) if len(s) else np.zeros(0, np.int64)
    att = _pick(a, rows, ("step", "acc_mg", "gyro_mdps", "thr", "q_wxyz", "thx_rad", "thy_rad", "t_fw_s"))
    sta = _pick(s, srows, ("step", "q_wxyz", "int_xyz", "kp_ground", "kp_flight", "ki", "dt_s", "min_thr", "flags"))
    return SimpleNamespace(attitude=att, status=sta), rows


#: what each change says of the firmware build (``{v}``: its value; ``{b}``: the settings the status frames report)
_CHANGE_SENTENCES = {
    "ki": "KI={v:g}: was the firmware built with AHRS_KI={v:g}f (ETH exercise 4)?",
    "correction": "the accelerometer correction on, though the status frames say it is off",
    "no correction": "no accelerometer correction (g* = g): was the correction commented out (ETH exercise 5)?",
    "variant": "the filter of {v} ({name})",
    "kp": "kp_ground={v[0]:g}, kp_flight={v[1]:g} (status/default {b.kp_ground:g}, {b.kp_flight:g}): were "
    "AHRS_KP_BIG/AHRS_KP_NORM changed?",
    "dt_s": "dt={v:.7g} s (status/default {b.dt_s:g} s): was SENSOR_SAMPLING_TIME changed to the real main-loop "
    "period?",
    "min_thr": "MIN_THR={v} (status/default {b.min_thr}): was the gain-switch threshold changed?",
    "defaults": "the firmware's default settings: the status frames report settings the filter does not use (or "
    "the replica was given other settings)",
}


def _describe_variant(changes: dict[str, Any], base: MahonySettings) -> str:
    """A sentence naming the firmware build that ``changes`` (field → value) describe."""
    keys = ["no correction" if k == "correction" and not v else k for k, v in changes.items()]
    return "; ".join(
        _CHANGE_SENTENCES[key].format(v=v, b=base, name=VARIANTS.get(v) if key == "variant" else None)
        for key, v in zip(keys, changes.values())
    )


def _cli_flags(s: MahonySettings, base: MahonySettings) -> str:
    """The settings (``name=value``) that run the replica with ``s`` when the status frames report ``base``."""
    floats = ("ki", "kp_ground", "kp_flight", "dt_s")
    out = [f"{k}={getattr(s, k):.9g}" for k in floats if np.float32(getattr(s, k)) != np.float32(getattr(base, k))]
    out += [f"{k}={getattr(s, k)}" for k in ("min_thr", "correction", "variant") if getattr(s, k) != getattr(base, k)]
    return " ".join(out)


def _variants(base: MahonySettings) -> list[tuple[dict[str, Any], MahonySettings]]:
    """Single-change alternatives to ``base`` the diagnosis tries, most common student edits first."""
    out: list[tuple[dict[str, Any], MahonySettings]] = []

    def add(changes: dict[str, Any], s: MahonySettings) -> None:
        if not _same_settings(s, base) and not any(_same_settings(s, o) for _, o in out):
            out.append((changes, s))

    defaults = MahonySettings()
    add({"defaults": True}, defaults)
    for ki in (1.0, C.KI, 0.0):
        add({"ki": ki}, replace(base, ki=ki))
    add({"correction": not base.correction}, replace(base, correction=not base.correction))
    for variant in VARIANTS:
        add({"variant": variant}, replace(base, variant=variant))
    for dt in (_DT_REAL_S, float(np.float32(C.AHRS_PERIOD_S)), C.DT_S):
        add({"dt_s": dt}, replace(base, dt_s=dt))
    for kg, kf in ((base.kp_flight,) * 2, (base.kp_ground,) * 2, (base.kp_flight, base.kp_ground), _KP_DEFAULTS):
        add({"kp": (kg, kf)}, replace(base, kp_ground=kg, kp_flight=kf))
    add({"min_thr": C.MIN_THR}, replace(base, min_thr=C.MIN_THR))
    return out


def _combine(a: tuple[dict, MahonySettings], b: tuple[dict, MahonySettings], base: MahonySettings):
    """Both changes at once (None when they touch the same field or either is 'defaults')."""
    ca, cb = a[0], b[0]
    if "defaults" in ca or "defaults" in cb or set(ca) & set(cb):
        return None
    s = base
    for ch in (ca, cb):
        for k, v in ch.items():
            s = replace(s, kp_ground=v[0], kp_flight=v[1]) if k == "kp" else replace(s, **{k: v})
    return {**ca, **cb}, s


def _window_exact(view, seed_state: MahonyState, settings: MahonySettings, r0: int, r1: int) -> int:
    """Rows from ``r0`` (the seed row) that the replica reproduces bit for bit in a row, up to ``r1`` (exclusive)."""
    a, rows = view.attitude, slice(r0, r1)
    q, thx, thy, _ = mahony_run(a.acc_mg[rows], a.gyro_mdps[rows], a.thr[rows], settings=settings, state=seed_state)
    ok = bits_equal(q, a.q_wxyz[rows]).all(axis=1) & bits_equal(thx, a.thx_rad[rows]) & bits_equal(thy, a.thy_rad[rows])
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else r1 - r0


def _diagnose(
    view, rep: FirmwareReplay, settings_override: MahonySettings | None, stats
) -> tuple[list[str], dict | None, int | None, MahonySettings | None]:
    """Why the replica disagrees: (sentences, matching variant, its bit-exact rows over the capture, its settings)."""
    steps = view.attitude.step
    m = rep.first_mismatch
    seed = max((s for s in rep.seeds if s.row <= m), key=lambda s: s.row)
    breaks = np.flatnonzero(np.diff(steps) != 1) + 1
    seg_end = int(breaks[np.searchsorted(breaks, m, side="right")]) if np.any(breaks > m) else steps.size
    # candidates start from the last snapshot before the mismatch (the replica was exact up to there), else the seed
    r0, state = seed.row, MahonyState()
    if seed.source == "status":
        state = MahonyState(q_wxyz=view.status.q_wxyz[seed.status_row], int_xyz=view.status.int_xyz[seed.status_row])
    st_steps = np.asarray(view.status.step, dtype=np.int64)
    k = np.flatnonzero((st_steps >= steps[seed.row]) & (st_steps < steps[m]))
    if k.size:
        j = int(k[np.argmax(st_steps[k])])
        r0 = seed.row + int(st_steps[j]) + 1 - int(steps[seed.row])
        state = MahonyState(q_wxyz=view.status.q_wxyz[j], int_xyz=view.status.int_xyz[j])
    found = _search_settings(view, state, seed.settings, r0, min(seg_end, m + DIAGNOSIS_WINDOW_ROWS))
    if found is not None:
        return _explained(view, *found, seed.settings, settings_override)
    seg_start = int(breaks[np.searchsorted(breaks, seed.row, side="right") - 1]) if np.any(breaks <= seed.row) else 0
    at_restart = seed.source == "status" and m - seed.row < 2
    lines = _restart_lines(view, seed, seg_start) if at_restart else []
    if int(stats.crc_failures) > 0:  # damage shown (skipped bytes alone are boot text or a late start, not damage)
        lines.append(
            f"the stream had {int(stats.crc_failures)} CRC failures and {int(stats.bytes_skipped)} skipped "
            "bytes: damaged frames are dropped, but a corrupted frame that passes its CRC would also do this"
        )
    one_off = _one_off_line(view, m, seg_end, seed.settings)
    if one_off is not None:
        lines.append(one_off)
    elif not at_restart:
        lines.append(
            "no known setting reproduces it (tried: firmware defaults, KI 1.0/0.1/0, correction on/off, "
            "the filters of ST's releases, dt 1/161.5 s and 5/807.7 s, kp variants, MIN_THR 200, and pairs "
            "of these): unknown firmware variant — was ahrs.c or QuaternionToEuler modified, or the "
            "firmware built with other compiler options (FMA, -O2 reordering)?"
        )
    return lines, None, None, None


def _search_settings(view, state: MahonyState, base: MahonySettings, r0: int, r1: int):
    """The first alternative setting (then pair of them) bit-exact on rows ``r0``..``r1``: (changes, settings)."""
    candidates = _variants(base)
    for ch, s in candidates:
        if _window_exact(view, state, s, r0, r1) == r1 - r0:
            return ch, s
    for x, y in combinations(candidates, 2):  # _combine skips "defaults" and pairs touching one field
        c = _combine(x, y, base)
        if c is not None and _window_exact(view, state, c[1], r0, r1) == r1 - r0:
            return c
    return None


def _explained(view, ch: dict, s: MahonySettings, base: MahonySettings, settings_override):
    """The setting that reproduces the firmware, replayed over the whole capture: as :func:`_diagnose` returns."""
    full = replay_firmware(view, settings=s)
    lines = [f"the capture matches {_describe_variant(ch, base)}"]
    flags = _cli_flags(s, _status_base(view) or MahonySettings())
    how = f" (settings {flags})" if flags else ""
    exact = f"all {full.n_seeded}" if full.all_exact else f"{full.n_bit_exact} of {full.n_seeded}"
    lines.append(f"with these settings the replica is bit-exact on {exact} seeded steps{how}")
    variant = {k: (list(v) if isinstance(v, tuple) else v) for k, v in ch.items()}
    if settings_override is not None and _same_settings(s, _status_base(view)):
        lines.append("these are the settings the status frames report: the settings override is wrong")
    return lines, variant, full.n_bit_exact, s


def _restart_lines(view, seed, seg_start: int) -> list[str]:
    """A mismatch right after the replica restarted from a status snapshot: where, and whether the snapshot fits."""
    steps = view.attitude.step
    snap = int(view.status.step[seed.status_row])
    where = (
        f"frames were dropped before that point (seq gap at step {int(steps[seg_start - 1])}→"
        f"{int(steps[seg_start])}); the replica restarted there"
        if seg_start > 0
        else "the replica started"
    )
    return [f"{where} from the status snapshot of step {snap}, which does not reproduce the next step"] + (
        _snapshot_check(view, seed.status_row)
        or ["the snapshot and the attitude frames may not belong together (firmware-side race, or a damaged frame)"]
    )


def _one_off_line(view, m: int, seg_end: int, base: MahonySettings) -> str | None:
    """Restarted from the next snapshot after row ``m``, does the replica agree again? (a one-off disturbance)"""
    st, steps = view.status, view.attitude.step
    k = np.flatnonzero((st.step >= steps[m]) & (st.step < steps[seg_end - 1]))
    if not k.size:
        return None
    j = int(k[np.argmin(st.step[k])])
    r0 = m + int(st.step[j]) + 1 - int(steps[m])
    if r0 >= seg_end:
        return None
    r1 = min(seg_end, r0 + DIAGNOSIS_WINDOW_ROWS)
    good = _window_exact(view, MahonyState(q_wxyz=st.q_wxyz[j], int_xyz=st.int_xyz[j]), base, r0, r1)
    if good != r1 - r0:
        return None
    return (
        f"restarted from the next status snapshot (step {int(st.step[j])}) the replica agrees "
        f"again for {good} steps: a one-off disturbance around step {int(steps[m])} rather "
        "than a different filter"
    )


def _snapshot_check(view, j: int) -> list[str]:
    """Is status snapshot ``j`` consistent with the attitude frame of its own step? (q must be the same bits.)"""
    st, a = view.status, view.attitude
    snap = int(st.step[j])
    r = np.flatnonzero(a.step == snap)
    if r.size == 0:
        return []
    same_q = bool(bits_equal(st.q_wxyz[j], a.q_wxyz[r[0]]).all())
    ints = ", ".join(f"{float(v):.6g}" for v in st.int_xyz[j])
    if same_q:
        return [
            f"the snapshot of step {snap} carries the same q as that step's attitude frame, so its integral "
            f"terms exInt/eyInt/ezInt ({ints}) must be wrong: does the firmware (or the tool that wrote the "
            "capture) report the integrals of that step?"
        ]
    return [
        f"the snapshot of step {snap} does not carry the q of that step's attitude frame: the snapshot was "
        "taken at another step (race between the AHRS step and the status frame in the firmware)"
    ]


def _status_base(view) -> MahonySettings | None:
    s = view.status
    return MahonySettings.of_status(s, int(np.argmin(s.step))) if s.step.size else None


def _vec(v, fmt: str = ".6g") -> str:
    return "(" + ", ".join(format(float(x), fmt) for x in np.asarray(v).reshape(-1)) + ")"


def q_norm(q) -> float:
    """|q| in float64 (inf or NaN for a non-finite q, without a warning)."""
    q = np.asarray(q, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.sqrt((q * q).sum()))


def find_divergence(view, rows: np.ndarray, rep: FirmwareReplay | None) -> dict[str, Any] | None:
    """The first binary row where the firmware's q leaves the unit sphere or goes non-finite (None: none): its step,
    q, the inputs of that step and the one before, what the replica (``rep``) did, and the sentences saying so."""
    a = view.attitude
    off = q_off_sphere(a.q_wxyz)
    if not off.any():
        return None
    k = int(np.argmax(off))
    step = int(a.step[k])
    q = np.asarray(a.q_wxyz[k], dtype=np.float64)
    fin = ~np.isfinite(np.asarray(a.q_wxyz, dtype=np.float64)).all(axis=1)
    first_nan = int(a.step[int(np.argmax(fin))]) if fin.any() else None
    t_fw = float(a.t_fw_s[k])
    inputs = [
        {
            "step": int(a.step[j]),
            "acc_mg": [json_number(x) for x in a.acc_mg[j]],
            "gyro_mdps": [json_number(x) for x in a.gyro_mdps[j]],
            "thr": int(a.thr[j]),
        }
        for j in (k - 1, k)
        if j >= 0 and int(a.step[j]) == step - (k - j)
    ]
    replica_state, replica_q, replica_div = "unseeded", None, None
    if rep is not None and bool(rep.seeded[k]):
        replica_q = [json_number(x) for x in rep.q_wxyz[k]]
        seeded_after = np.flatnonzero(rep.seeded[k:]) + k
        p_off = q_off_sphere(rep.q_wxyz[seeded_after])
        replica_state = "diverged" if p_off.any() else "finite"
        replica_div = int(a.step[seeded_after[int(np.argmax(p_off))]]) if p_off.any() else None
    nonfinite = not np.isfinite(q).all()
    what = "went non-finite" if nonfinite else "left the unit sphere"
    how = "" if nonfinite else f", |q| = {q_norm(q):.6g}"
    text = [
        f"the firmware's own filter {what} at step {step} (t = {t_fw:.3f} s): q = {_vec(q)}{how} (the "
        f"release keeps |q| ≈ 0.9983)"
        + (f"; non-finite from step {first_nan} on" if first_nan is not None and first_nan != step else "")
    ]
    text += [
        f"inputs at step {inp['step']}: acc {_vec(inp['acc_mg'], '.5g')} mg, gyro "
        f"{_vec(inp['gyro_mdps'], '.5g')} mdps, thr {inp['thr']}"
        for inp in inputs
    ]
    if len(inputs) < 2:
        text.append(f"the step before ({step - 1}) was not received")
    text.append(_replica_divergence_line(replica_state, replica_q, replica_div, step))
    return {
        "row": int(rows[k]),
        "step": step,
        "t_fw_s": json_number(t_fw),
        "q_wxyz": [json_number(x) for x in q],
        "q_norm": json_number(q_norm(q)),
        "first_nonfinite_step": first_nan,
        "inputs": inputs,
        "replica": replica_state,
        "replica_q_wxyz": replica_q,
        "replica_diverged_step": replica_div,
        "text": text,
    }


def _replica_divergence_line(state: str, q, diverged_step: int | None, step: int) -> str:
    """What the replica did on the inputs where the firmware's filter diverged, and what that blames."""
    if state == "finite":
        return (
            f"the bit-exact replica stayed finite on the same inputs (q = {_vec(q)}, |q| = "
            f"{q_norm(q):.6g} at step {step}, on the unit sphere to the end): the firmware's "
            "ahrs_fusion_ag is not release 170120's; check the quaternion update and the normalisation in "
            "ahrs.c (no setting of the release's filter takes its q off the unit sphere on inputs the replica "
            "handles, so none was searched)"
        )
    if state == "diverged":
        return (
            f"the replica diverged too on the same inputs (from step {diverged_step}): the inputs drive the filter "
            "out of range; check the sensor values and the settings"
        )
    return (
        "the replica had no state at that step (no power-up and no finite status snapshot before it), so "
        "it cannot tell whether the filter or its inputs are to blame"
    )


def compare_replica(
    tel, settings: MahonySettings | None = None, *, variant: str | None = None, variant_source: str = "variant setting"
) -> tuple[ReplicaComparison | None, FirmwareReplay | None, np.ndarray | None]:
    """(report, replay, binary rows) of the seeded replica against the firmware, (None, None, None) without binary
    rows; ``variant`` forces a release, else the one bit-exact on the most steps."""
    view, rows = _binary_view(tel)
    if rows.size == 0:
        return None, None, None
    chosen = replay_variants(view, settings, variant=variant, source=variant_source, hint=capture_variant_hint(tel))
    rep = chosen.replay
    if settings is not None:
        settings = replace(settings, variant=chosen.variant)
    fallback = replace(_status_base(view) or MahonySettings(), variant=chosen.variant)
    used = settings or (rep.seeds[0].settings if rep.seeds else fallback)
    seeds = [
        {
            "row": int(rows[s.row]),
            "step": s.step,
            "source": s.source,
            "status_row": None if s.status_row is None else int(s.status_row),
        }
        for s in rep.seeds
    ]
    divergence = find_divergence(view, rows, rep)
    first, diagnosis, matching, matching_exact = _first_mismatch(tel, view, rows, rep, settings, divergence)
    comparison = ReplicaComparison(
        rows=int(rows.size),
        seeded=rep.n_seeded,
        bit_exact=rep.n_bit_exact,
        seeds=seeds,
        first_mismatch=first,
        settings=_settings_dict(used),
        diagnosis=diagnosis,
        matching_variant=matching,
        matching_bit_exact=matching_exact,
        unseeded_reason=_unseeded_reason(view, rep),
        divergence=divergence,
        filter=chosen.variant,
        filter_from=chosen.source,
        variant_bit_exact=chosen.bit_exact,
    )
    return comparison, rep, rows


def _unseeded_reason(view, rep: FirmwareReplay) -> str | None:
    """Why the replica never started (None: it did)."""
    if rep.n_seeded:
        return None
    if view.status.step.size == 0:
        return (
            "the capture does not start at step 0 (power-up) and has no status frame with a filter "
            "snapshot, so the replica has no state to start from"
        )
    return "no status snapshot falls inside a run of consecutive steps, so the replica has no state to start from"


def _first_mismatch(tel, view, rows, rep: FirmwareReplay, settings, divergence):
    """The first row that differs, the diagnosis, the matching variant and its bit-exact rows."""
    if rep.first_mismatch is None:  # no step to compare with (the replica had no state): the divergence alone
        return None, ([] if divergence is None else list(divergence["text"])), None, None
    a = view.attitude
    m = rep.first_mismatch
    t_rel = relative_time_s(tel.attitude.step, tel.attitude.t_fw_s)
    first = {
        "row": int(rows[m]),
        "step": int(a.step[m]),
        "t_fw_s": float(a.t_fw_s[m]),
        "t_rel_s": float(t_rel[rows[m]]),
    }
    if divergence is not None and divergence["replica"] == "finite":
        return first, list(divergence["text"]), None, None  # no setting of the release's filter explains a NaN
    diagnosis, variant, variant_exact, _ = _diagnose(view, rep, settings, tel.stats)
    if divergence is not None:
        diagnosis = list(divergence["text"]) + diagnosis
    return first, diagnosis, variant, variant_exact


def recognise_release(tel, *, variant: str | None = None, source: str = "variant setting") -> dict[str, Any] | None:
    """The ST release whose filter reproduces the binary rows (``variant`` forces one), or None without binary rows."""
    view, rows = _binary_view(tel)
    if rows.size == 0:
        return None
    chosen = replay_variants(view, variant=variant, source=source, hint=capture_variant_hint(tel))
    rep = chosen.replay
    first = None if rep.first_mismatch is None else int(view.attitude.step[rep.first_mismatch])
    return {
        "filter": chosen.variant,
        "from": chosen.source,
        "variant_bit_exact_steps": chosen.bit_exact,
        "bit_exact_steps": rep.n_bit_exact,
        "seeded_steps": rep.n_seeded,
        "text": release_sentence(
            chosen.variant,
            chosen.source,
            chosen.bit_exact,
            seeded=rep.n_seeded,
            exact=rep.n_bit_exact,
            first_mismatch_step=first,
        ),
    }


def capture_variant_hint(tel) -> tuple[str, str] | None:
    """(variant, who named it) from an emulated capture's header (``extra.filter``), or None."""
    extra = ((getattr(tel, "source", None) or {}).get("header") or {}).get("extra") or {}
    f = extra.get("filter")
    if not isinstance(f, dict) or f.get("variant") not in VARIANTS:
        return None
    return f["variant"], str(f.get("from") or "capture header")
