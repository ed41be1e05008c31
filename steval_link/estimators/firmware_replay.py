"""The firmware filter's replica followed along status snapshots and attitude rows, next to the firmware's outputs."""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from steval_link.estimators.st_mahony import (
    DEFAULT_VARIANT,
    VARIANTS,
    MahonySettings,
    MahonyState,
    bits_equal,
    quaternion_to_euler,
    run,
    table_column,
)
from steval_link.fw_math import _F32
from steval_link.link.protocol import FLAG_EVENT


class ReplicaFollower:
    """The bit-exact replica along attitude rows and status snapshots (replay and live). It starts at power-up (a run
    of consecutive steps from step 0) or from a snapshot; a step gap or an unusable row (text mode, non-finite)
    leaves it unseeded (NaN) until the next one.

    ``settings``: fixed for every seed (a what-if replay); None: each snapshot's own, ``initial`` at power-up.
    ``follow_snapshots``: an in-sync snapshot is confirmed when bit-equal, else seeds (True, live) or is ignored
    (False, a replay). An EVENT snapshot (a host command changed the filter) is always followed. ``variant``: the
    release every settings runs with (None: their own)."""

    def __init__(
        self,
        settings: MahonySettings | None = None,
        *,
        initial: MahonySettings | None = None,
        follow_snapshots: bool = True,
        euler: bool = True,
        variant: str | None = None,
    ) -> None:
        self.variant = variant
        self.fixed = self._with_variant(settings)
        self.settings = self._with_variant(settings or initial or MahonySettings())
        self.follow_snapshots = follow_snapshots
        self.euler = euler
        self._run = functools.partial(run, euler=euler)
        self.state: MahonyState | None = None
        self.next_step: int | None = None
        self.seed_count = 0  #: (re)starts of the replica so far (power-up or snapshot)
        self.confirmed = 0  #: snapshots that matched the replica's own state and settings bit for bit
        self._pending: tuple[str, int | None, MahonySettings] | None = None
        #: (first row of the seed in the caller's numbering, seed) of every seed, once its first row ran
        self.seed_rows: list[tuple[int, tuple[str, int | None, MahonySettings]]] = []

    def _with_variant(self, settings: MahonySettings | None) -> MahonySettings | None:
        if settings is None or self.variant is None or settings.variant == self.variant:
            return settings
        return replace(settings, variant=self.variant)

    def force_variant(self, variant: str | None) -> None:
        """Run every settings with ``variant``'s filter from now on."""
        self.variant = variant
        self.fixed = self._with_variant(self.fixed)
        self.settings = self._with_variant(self.settings)

    @property
    def seeded(self) -> bool:
        return self.state is not None

    def snapshot(
        self,
        step: int,
        state: MahonyState,
        settings: MahonySettings,
        snapshot_id: int | None = None,
        *,
        event: bool = False,
    ) -> str:
        """The firmware's filter state right after step ``step``: "confirmed", "seeded" or "ignored". A non-finite
        snapshot (the firmware's filter diverged) seeds nothing, but the replica takes its settings (unless fixed)."""
        settings = self._with_variant(settings)
        in_sync = self.state is not None and self.next_step == step + 1
        if in_sync and not (self.follow_snapshots or event):
            return "ignored"
        if in_sync and (self.fixed is not None or settings == self.settings) and self.state.bits_equal(state):
            self.confirmed += 1
            return "confirmed"
        if not np.all(np.isfinite(state.as_array())):
            if self.fixed is None and (self.follow_snapshots or event or self.state is None):
                self.settings = settings
            return "ignored"
        self.state = state
        self.settings = self.fixed or settings
        self.next_step = step + 1
        self._pending = ("status", snapshot_id, self.settings)
        self.seed_count += 1
        return "seeded"

    def _saved(self) -> dict:
        return {**vars(self), "seed_rows": list(self.seed_rows)}

    def _restore(self, saved: dict) -> None:
        vars(self).update(saved, seed_rows=list(saved["seed_rows"]))

    def rows_recognising(self, step, acc_mg, gyro_mdps, thr, usable, fw_q_wxyz, *, first_row: int = 0):
        """:meth:`rows`; when no ``variant`` is named and they differ from the firmware's ``fw_q_wxyz``, the same rows
        again with each other release's filter: the first bit-exact on all of them is kept from then on."""
        saved = self._saved()
        out = self.rows(step, acc_mg, gyro_mdps, thr, usable, first_row=first_row)
        if self.variant is not None or not _differs(out, fw_q_wxyz):
            return out
        after = self._saved()
        running = self.settings.variant
        for variant in (v for v in VARIANTS if v != running):
            self._restore(saved)
            self.force_variant(variant)
            if self._pending is not None:
                self._pending = (*self._pending[:2], self.settings)
            trial = self.rows(step, acc_mg, gyro_mdps, thr, usable, first_row=first_row)
            if trial[3].any() and not _differs(trial, fw_q_wxyz):
                return trial
        self._restore(after)
        return out

    def rows(self, step, acc_mg, gyro_mdps, thr, usable, *, first_row: int = 0):
        """Step the replica over these attitude rows, in stream order: q (N, 4), thx, thy (None without ``euler``),
        seeded (N,) bool; NaN where unseeded."""
        step = np.asarray(step, dtype=np.int64)
        n = step.shape[0]
        q = np.full((n, 4), np.nan, dtype=_F32)
        thx, thy = np.full((2, n), np.nan, dtype=_F32) if self.euler else (None, None)
        seeded = np.zeros(n, dtype=bool)
        breaks = np.flatnonzero((np.diff(step) != 1) | ~usable[1:] | ~usable[:-1]) + 1
        for a, b in zip(np.concatenate(([0], breaks)).tolist(), np.concatenate((breaks, [n])).tolist()):
            if a >= b:
                continue
            if not usable[a]:
                self.state = self.next_step = None
                continue
            s0 = int(step[a])
            if self.state is not None and self.next_step != s0:
                self.state = None  # frames lost: out of sync until the next snapshot
            if self.state is None and s0 == 0:
                self.state = MahonyState()  # the stream starts at power-up
                self._pending = ("power-up", None, self.settings)
                self.seed_count += 1
            if self.state is not None:
                if self._pending is not None:
                    self.seed_rows.append((first_row + a, self._pending))
                    self._pending = None
                out = self._run(acc_mg[a:b], gyro_mdps[a:b], thr[a:b], settings=self.settings, state=self.state)
                q[a:b], self.state = out[0], out[3]
                if self.euler:
                    thx[a:b], thy[a:b] = out[1], out[2]
                seeded[a:b] = True
            self.next_step = int(step[b - 1]) + 1
        return q, thx, thy, seeded


def _differs(rows_out, fw_q_wxyz) -> bool:
    """True when a seeded row of :meth:`ReplicaFollower.rows`' output differs from the firmware's q."""
    q, _, _, seeded = rows_out
    return bool((seeded & ~bits_equal(q, np.asarray(fw_q_wxyz, dtype=_F32)).all(axis=1)).any())


@dataclass(frozen=True)
class ReplaySeed:
    """Where the replica (re)started during a replay: attitude row ``row`` (AHRS step ``step``) onwards, from
    ``source`` "power-up" or "status" (the snapshot of status row ``status_row``, taken after step ``step - 1``)."""

    row: int
    step: int
    source: str
    status_row: int | None
    settings: MahonySettings


@dataclass(frozen=True)
class FirmwareReplay:
    """The replica re-run over a capture, per attitude row: its float32 ``q_wxyz``, ``thx_rad`` (pitch, about x) and
    ``thy_rad`` (roll, about y), NaN where not ``seeded``; ``bit_exact`` where all carry the firmware's bits (NaN ==
    NaN); ``first_mismatch`` the first seeded row that is not (or None); ``seeds`` every (re)start, in row order."""

    q_wxyz: np.ndarray
    thx_rad: np.ndarray
    thy_rad: np.ndarray
    bit_exact: np.ndarray
    seeded: np.ndarray
    first_mismatch: int | None
    seeds: tuple[ReplaySeed, ...]

    @property
    def n_seeded(self) -> int:
        return int(np.count_nonzero(self.seeded))

    @property
    def n_bit_exact(self) -> int:
        return int(np.count_nonzero(self.bit_exact))

    @property
    def all_exact(self) -> bool:
        """True when every seeded row is bit-exact (and at least one row is seeded)."""
        return self.n_seeded > 0 and self.first_mismatch is None


def replay_firmware(tel, settings: MahonySettings | None = None, *, variant: str | None = None) -> FirmwareReplay:
    """Re-run the replica over a capture (a :class:`~steval_link.link.telemetry.Telemetry`) and compare it with the
    firmware's outputs, bit for bit. ``settings`` default: the status frames' (else the firmware's defaults);
    ``variant`` default: the settings' own. Seeds as :class:`ReplicaFollower`; rows before a seed are NaN."""
    rows = _AttitudeRows.of(tel.attitude)
    snaps = _Snapshots.of(getattr(tel, "status", None))
    initial = settings or snaps.default_settings()
    replica = ReplicaFollower(settings, initial=initial, follow_snapshots=False, variant=variant)
    steps, exact_rows, n = rows.steps, rows.exact, len(rows.steps)
    parts = [rows.run(replica, 0, 0)]  # no row yet: the empty arrays of each output
    # in stream order: each run of consecutive exact rows, seeded at power-up or by the first snapshot inside it
    breaks = np.flatnonzero((np.diff(steps) != 1) | (exact_rows[1:] != exact_rows[:-1])) + 1
    for a, b in zip(np.concatenate(([0], breaks)).tolist(), np.concatenate((breaks, [n])).tolist()):
        if a < b:
            parts += _replay_run(replica, rows, snaps, a, b)
    q, thx, thy, seeded = (np.concatenate([p[i] for p in parts]) for i in range(4))
    seeds = [ReplaySeed(row, int(steps[row]), src, sid, st) for row, (src, sid, st) in replica.seed_rows]
    exact = seeded & bits_equal(q, rows.fw_q).all(axis=1) & bits_equal(thx, rows.fw_thx) & bits_equal(thy, rows.fw_thy)
    bad = np.flatnonzero(seeded & ~exact)
    first_mismatch = int(bad[0]) if bad.size else None
    return FirmwareReplay(q, thx, thy, exact, seeded, first_mismatch, tuple(seeds))


@dataclass(frozen=True)
class _AttitudeRows:
    """A capture's attitude rows as the replay reads them: the filter's inputs, the firmware's outputs, and which
    rows are exact filter inputs (rounded text-mode rows are never replayed)."""

    steps: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    thr: np.ndarray
    exact: np.ndarray
    fw_q: np.ndarray
    fw_thx: np.ndarray
    fw_thy: np.ndarray

    @classmethod
    def of(cls, att) -> _AttitudeRows:
        steps = np.asarray(table_column(att, "step"), dtype=np.int64)

        def col(name: str, dtype, *shape) -> np.ndarray:
            return np.ascontiguousarray(table_column(att, name), dtype=dtype).reshape(steps.shape[0], *shape)

        fw_q = col("q_wxyz", _F32, 4)
        try:
            fw_thx, fw_thy = col("thx_rad", _F32), col("thy_rad", _F32)
        except (AttributeError, KeyError, ValueError):
            fw_thx, fw_thy = quaternion_to_euler(fw_q)
        try:
            exact = col("exact", bool)
        except (AttributeError, KeyError, ValueError):
            exact = np.ones(steps.shape[0], dtype=bool)
        return cls(
            steps, col("acc_mg", _F32, 3), col("gyro_mdps", _F32, 3), col("thr", np.int64), exact, fw_q, fw_thx, fw_thy
        )

    def run(self, replica: ReplicaFollower, a: int, b: int):
        """The replica over rows ``a:b``."""
        sl = slice(a, b)
        return replica.rows(self.steps[sl], self.acc[sl], self.gyro[sl], self.thr[sl], self.exact[sl], first_row=a)


@dataclass(frozen=True)
class _Snapshots:
    """The status frames that carry a filter snapshot, by step: ``order`` (their rows), ``steps`` (sorted),
    ``events`` (per status row: sent because of a host command) and ``has_settings`` (per status row)."""

    status: object
    order: np.ndarray
    steps: np.ndarray
    events: np.ndarray
    has_settings: np.ndarray

    @classmethod
    def of(cls, status) -> _Snapshots:
        def col(name: str, dtype=np.float64) -> np.ndarray:
            return np.asarray(table_column(status, name), dtype=dtype)

        st_steps = np.zeros(0, dtype=np.int64) if status is None else col("step", np.int64)
        order = np.zeros(0, dtype=np.int64)
        events = has_settings = np.zeros(st_steps.shape[0], dtype=bool)
        if st_steps.size:
            # Only binary status frames carry a snapshot and the settings; text-mode $STA rows hold NaN there.
            usable = np.isfinite(col("kp_ground")) & np.isfinite(col("q_wxyz")).all(axis=1)
            usable &= np.isfinite(col("int_xyz")).all(axis=1)
            st_steps = np.where(usable, st_steps, -1)  # -1 never matches a snapshot step
            order = np.flatnonzero(usable)[np.argsort(st_steps[usable], kind="stable")]
            events = (col("flags", np.int64) & FLAG_EVENT) != 0
            has_settings = np.all([np.isfinite(col(k)) for k in ("kp_ground", "kp_flight", "ki", "dt_s")], axis=0)
        return cls(status, order, st_steps[order], events, has_settings)

    def default_settings(self) -> MahonySettings:
        """The build's settings: the first snapshot's, else the first status frame's that reports them (a diverged
        filter's snapshot holds NaN), else the firmware's defaults."""
        first = np.concatenate([self.order[:1], np.flatnonzero(self.has_settings)[:1]])
        return MahonySettings.of_status(self.status, int(first[0])) if first.size else MahonySettings()

    def state(self, j: int) -> MahonyState:
        return MahonyState(table_column(self.status, "q_wxyz")[j], table_column(self.status, "int_xyz")[j])


def _replay_run(replica: ReplicaFollower, rows: _AttitudeRows, snaps: _Snapshots, a: int, b: int) -> list:
    """The replica over one run ``a:b`` of consecutive rows, in pieces between the snapshots inside it (the replica
    takes one when unseeded or an EVENT, and ignores the others)."""
    parts = []
    cut = a
    if rows.exact[a]:
        s_first, s_last = int(rows.steps[a]), int(rows.steps[b - 1])
        lo = int(np.searchsorted(snaps.steps, s_first - 1, side="left"))
        for k in range(lo, int(np.searchsorted(snaps.steps, s_last - 1, side="right"))):
            j, step = int(snaps.order[k]), int(snaps.steps[k])
            end = a + step + 1 - s_first  # rows up to the snapshot's step
            if end > cut:
                parts.append(rows.run(replica, cut, end))
                cut = end
            settings = MahonySettings.of_status(snaps.status, j)
            replica.snapshot(step, snaps.state(j), settings, snapshot_id=j, event=bool(snaps.events[j]))
    parts.append(rows.run(replica, cut, b))
    return parts


@dataclass(frozen=True)
class VariantReplay:
    """The release whose filter reproduces a capture, ``source`` how it was chosen (who named it, "data", or
    "settings" when every variant is as exact), and ``bit_exact`` the steps of each variant tried (empty: forced)."""

    variant: str
    source: str
    replay: FirmwareReplay
    bit_exact: dict


def replay_variants(
    tel,
    settings: MahonySettings | None = None,
    *,
    variant: str | None = None,
    source: str = "variant setting",
    hint: tuple[str, str] | None = None,
) -> VariantReplay:
    """Replay the capture with ``variant`` (named by ``source``), else with each of ``VARIANTS``, keeping the most
    bit-exact; on a tie ``hint`` (variant, who named it) when given, else the settings' own."""
    if variant is not None:
        return VariantReplay(variant, source, replay_firmware(tel, settings, variant=variant), {})
    replays = {v: replay_firmware(tel, settings, variant=v) for v in VARIANTS}
    preferred = settings.variant if settings is not None else _status_variant(tel)
    counts = {v: r.n_bit_exact for v, r in replays.items()}
    best = max(counts.values())
    winners = [v for v, n in counts.items() if n == best]
    if hint is not None and hint[0] in winners:
        return VariantReplay(hint[0], hint[1], replays[hint[0]], counts)
    chosen = preferred if preferred in winners else winners[0]
    how = "data" if len(winners) == 1 else "settings"
    return VariantReplay(chosen, how, replays[chosen], counts)


def _status_variant(tel) -> str:
    """The variant the first binary status frame's flags announce (ST 170120 without one)."""
    snaps = _Snapshots.of(getattr(tel, "status", None))
    rows = np.flatnonzero(snaps.has_settings)
    return MahonySettings.of_status(snaps.status, int(rows[0])).variant if rows.size else DEFAULT_VARIANT


def release_sentence(
    variant: str, source: str, bit_exact: dict, *, seeded: int, exact: int, first_mismatch_step: int | None
) -> str:
    """The sentence naming the release a replay ran: recognised, forced or given, or the closest when none is
    bit-exact. ``bit_exact``: each variant's bit-exact steps (empty: forced)."""
    others = "; ".join(f"{v}: {n} of {seeded}" for v, n in bit_exact.items() if v != variant)
    others = f"; {others}" if others else ""
    if seeded == 0:
        return f"filter: {variant} assumed (no seeded step to recognise the release by)"
    step = "?" if first_mismatch_step is None else first_mismatch_step
    if exact < seeded and not bit_exact:
        return (
            f"filter: {variant} (from the {source}): bit-exact on {exact} of {seeded} steps, it leaves the firmware "
            f"at step {step}"
        )
    if exact < seeded:
        return (
            f"filter: no ST release's filter is bit-exact on every step; closest {variant} ({exact} of {seeded}; "
            f"it leaves the firmware at step {step}{others})"
        )
    how = {
        "firmware ELF": "recognised from the firmware ELF's code, and bit-exact on every step",
        "data": "recognised from the data: the only variant bit-exact on every step",
        "settings": "every variant is bit-exact on these steps: the status frames' or the default",
    }.get(source, f"from the {source}")
    return f"filter: {variant} ({how}{others})"
