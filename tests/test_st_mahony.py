"""The ST Mahony replica against the firmware's conformance vectors (bit for bit), both loops, and its options."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from steval_link.estimators import firmware_replay, registry, st_mahony
from steval_link.estimators.conformance import load_conformance_csv
from steval_link.estimators.firmware_replay import replay_firmware
from steval_link.estimators.st_mahony import (
    COE_MDPS_TO_RADPS_F32,
    MahonySettings,
    MahonyState,
    StMahony,
    bits_equal,
    inv_sqrt,
    quaternion_to_euler,
    run,
)
from steval_link.link.protocol import FLAG_FRESH_SQUARES, FLAG_NO_CORRECTION, STATUS_DTYPE
from steval_link.quat import euler_from_quaternion

CONFORMANCE_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "conformance" / "st-fcu-170120"
CSV_NAMES = sorted(p.name for p in CONFORMANCE_DIR.glob("*.csv")) if CONFORMANCE_DIR.is_dir() else []
needs_shared = pytest.mark.skipif(not CSV_NAMES, reason="shared conformance vectors (../shared) not present")
needs_native = pytest.mark.skipif(not st_mahony.NATIVE_AVAILABLE, reason="native Mahony loop not built")

_CACHE: dict[str, object] = {}


def vectors(name: str):
    if name not in _CACHE:
        _CACHE[name] = load_conformance_csv(CONFORMANCE_DIR / name)
    return _CACHE[name]


def assert_bits(actual, expected, what=""):
    eq = bits_equal(actual, expected)
    if not eq.all():
        idx = np.argwhere(~eq)[0]
        raise AssertionError(
            f"{what}: {np.count_nonzero(~eq)} values differ, first at {tuple(idx)}: "
            f"{np.asarray(actual)[tuple(idx)]!r} != {np.asarray(expected)[tuple(idx)]!r}"
        )


def random_inputs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    acc = rng.normal([0, 0, 1000], 300, size=(n, 3)).astype(np.float32)
    gyro = rng.normal(0, 40000, size=(n, 3)).astype(np.float32)
    thr = rng.integers(0, 900, size=n)
    acc[::97] = 0.0  # free fall samples: invSqrt(0)
    return acc, gyro, thr


# --------------------------------------------------------------------------------------------- conformance


def test_conformance_vectors_are_all_found():
    if not CONFORMANCE_DIR.is_dir():
        pytest.skip("shared conformance vectors (../shared) not present")
    assert {"lab5_baseline.csv", "edge_cases.csv", "broad_02.csv"} <= set(CSV_NAMES)


@needs_shared
@pytest.mark.parametrize("native", [pytest.param(True, marks=needs_native), False], ids=["native", "numpy"])
@pytest.mark.parametrize("name", CSV_NAMES)
def test_quaternion_to_euler_matches_firmware_bits(name, native):
    v = vectors(name)
    thx, thy = quaternion_to_euler(v.q_wxyz, native=native)
    assert thx.dtype == np.float32 and thy.dtype == np.float32
    assert_bits(thx, v.thx_rad, f"{name} thx")
    assert_bits(thy, v.thy_rad, f"{name} thy")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_shared
@pytest.mark.parametrize("native", [pytest.param(True, marks=needs_native), False], ids=["native", "numpy"])
@pytest.mark.parametrize("name", CSV_NAMES)
def test_port_is_bit_exact_on_every_row(name, native):
    v = vectors(name)
    q, thx, thy, _ = run(v.acc_mg, v.gyro_mdps, v.thr, native=native)
    assert_bits(q, v.q_wxyz, f"{name} q")
    assert_bits(thx, v.thx_rad, f"{name} thx")
    assert_bits(thy, v.thy_rad, f"{name} thy")


@needs_shared
def test_edge_cases_keep_the_firmware_nans_and_stale_norm():
    v = vectors("edge_cases.csv")
    q, thx, thy, _ = run(v.acc_mg, v.gyro_mdps, v.thr)
    nan_rows = np.flatnonzero(np.isnan(v.thy_rad))
    assert nan_rows.size > 0 and np.array_equal(np.flatnonzero(np.isnan(thy)), nan_rows)
    assert np.isfinite(q).all()  # the NaN comes from asin of the stale-normalised q, not from q itself
    base = vectors("lab5_baseline.csv")
    norm = np.linalg.norm(base.q_wxyz[-1].astype(np.float64))
    assert abs(norm - 0.9983) < 5e-4  # normalised with the squares from before the update


@needs_shared
@pytest.mark.parametrize("name", ["throttle_switch.csv", "broad_07.csv"])
def test_chunked_and_seeded_runs_continue_bit_exact(name):
    v = vectors(name)
    n = min(len(v), 6000)
    cut = n // 3
    q1, _, _, mid = run(v.acc_mg[:cut], v.gyro_mdps[:cut], v.thr[:cut])
    # a status snapshot is the float32 q + integrals; seeding from its values continues the firmware exactly
    snap = MahonyState(q_wxyz=np.array(mid.q_wxyz), int_xyz=np.array(mid.int_xyz))
    q2, thx2, _, _ = run(v.acc_mg[cut:n], v.gyro_mdps[cut:n], v.thr[cut:n], state=snap)
    assert_bits(np.concatenate([q1, q2]), v.q_wxyz[:n], "chunked q")
    assert_bits(thx2, v.thx_rad[cut:n], "seeded thx")


@needs_shared
def test_estimator_step_by_step_equals_the_firmware():
    v = vectors("lab5_noise.csv")
    est = registry.create("st-mahony")
    qs = np.array([est.step(v.acc_mg[k], v.gyro_mdps[k], int(v.thr[k])) for k in range(300)])
    assert_bits(qs, v.q_wxyz[:300], "step() q")
    est.reset()
    res = est.run(v.acc_mg, v.gyro_mdps, v.thr)
    assert_bits(res.q_wxyz, v.q_wxyz, "run() q")
    assert_bits(res.thx_rad, v.thx_rad, "run() thx")
    assert res.valid.all() and res.thz_rad.shape == (len(v),)


# --------------------------------------------------------------------------------------------- both loops agree


SETTINGS_VARIANTS = [
    MahonySettings(),
    MahonySettings(ki=1.0),
    MahonySettings(correction=False),
    MahonySettings(variant="ST 221117"),
    MahonySettings(variant="ST 221117", ki=0.3, dt_s=0.00619),
    MahonySettings(dt_s=0.00619, kp_ground=2.5, kp_flight=0.25, min_thr=20),
]


@needs_native
@pytest.mark.parametrize("settings", SETTINGS_VARIANTS, ids=lambda s: f"ki{s.ki}-c{s.correction}-{s.variant}")
def test_native_and_pure_loops_agree_bit_for_bit(settings):
    acc, gyro, thr = random_inputs(1500, seed=7)
    state = MahonyState(q_wxyz=(0.9, 0.1, -0.2, 0.3), int_xyz=(0.01, -0.02, 0.003))
    a = run(acc, gyro, thr, settings=settings, state=state, native=True)
    b = run(acc, gyro, thr, settings=settings, state=state, native=False)
    for x, y, what in zip(a[:3], b[:3], ("q", "thx", "thy")):
        assert_bits(x, y, what)
    assert a[3].bits_equal(b[3])


@needs_native
def test_loops_agree_on_extreme_inputs():
    # zeros, ±0, denormals, overflow to inf, inf, NaN and huge rates: C and numpy must round (and NaN) alike
    rng = np.random.default_rng(0)
    n = 3000
    specials = np.array(
        [0, -0.0, 1e-45, -1e-45, 1e-38, 3e38, -3e38, np.inf, -np.inf, np.nan, 1e20, 1, -2e6], np.float32
    )
    acc = rng.choice(specials, (n, 3)).astype(np.float32)
    gyro = rng.choice(specials, (n, 3)).astype(np.float32)
    normal = rng.random(n) < 0.8
    acc[normal] = rng.normal([0, 0, 1000], 500, (normal.sum(), 3))
    gyro[normal] = rng.normal(0, 1e5, (normal.sum(), 3))
    thr = rng.integers(-300, 900, n)
    for settings in (MahonySettings(), MahonySettings(variant="ST 221117"), MahonySettings(correction=False)):
        for seg in range(0, n, 25):  # restart often, or the first NaN would make the rest trivially NaN
            sl = slice(seg, seg + 25)
            state = MahonyState(q_wxyz=rng.normal(size=4), int_xyz=rng.normal(size=3) * 1e-2)
            a = run(acc[sl], gyro[sl], thr[sl], settings=settings, state=state, native=True)
            b = run(acc[sl], gyro[sl], thr[sl], settings=settings, state=state, native=False)
            for x, y, what in zip(a[:3], b[:3], ("q", "thx", "thy")):
                assert_bits(x, y, f"{what} segment {seg}")
            assert a[3].bits_equal(b[3])


@needs_shared
def test_pure_fallback_is_used_without_the_extension(monkeypatch):
    monkeypatch.setattr(st_mahony, "_native", None)
    monkeypatch.setattr(st_mahony, "NATIVE_AVAILABLE", False)
    v = vectors("throttle_switch.csv")
    q, thx, _, _ = run(v.acc_mg[:500], v.gyro_mdps[:500], v.thr[:500])
    assert_bits(q, v.q_wxyz[:500], "fallback q")
    with pytest.raises(RuntimeError, match="not built"):
        run(v.acc_mg[:5], v.gyro_mdps[:5], native=True)


def test_inputs_and_constants_are_the_firmwares():
    assert COE_MDPS_TO_RADPS_F32 == np.float32(1.745329252e-5)
    assert np.isfinite(inv_sqrt(np.float32(0.0)))  # free fall does not blow up
    assert abs(float(inv_sqrt(np.float32(4.0))) - 0.5) < 2e-3  # one Newton step: ~0.2 % error
    q, thx, thy, st = run(np.zeros((0, 3)), np.zeros((0, 3)))
    assert q.shape == (0, 4) and thx.shape == (0,) and st.bits_equal(MahonyState())


def test_kp_switches_on_throttle():
    acc = np.tile(np.float32([300, -200, 900]), (50, 1))
    gyro = np.zeros((50, 3), np.float32)
    ground = run(acc, gyro, np.zeros(50, int))[0]
    flight = run(acc, gyro, np.full(50, 450))[0]
    same_gain = run(acc, gyro, np.full(50, 450), settings=MahonySettings(kp_flight=10.0))[0]
    assert_bits(ground, same_gain, "kp_ground == kp_flight=10 in flight")
    assert not bits_equal(ground, flight).all()
    # exactly at MIN_THR the firmware uses the flight gain (gTHR < MIN_THR is false)
    assert_bits(run(acc, gyro, np.full(50, 200))[0], flight, "thr == MIN_THR")


def test_no_correction_ignores_the_accelerometer_and_freezes_the_integral():
    s = MahonySettings(correction=False)
    gyro = np.tile(np.float32([1000, -3000, 500]), (40, 1))
    seed = MahonyState(int_xyz=(0.5, 0.25, -0.125))
    qa, _, _, sa = run(np.zeros((40, 3)), gyro, settings=s, state=seed)
    qb, _, _, sb = run(np.full((40, 3), 700.0), gyro, settings=s, state=seed)
    assert_bits(qa, qb, "q with different acc")
    assert sa.int_xyz == seed.int_xyz
    assert not bits_equal(qa, run(np.zeros((40, 3)), gyro, state=seed)[0]).all()


def test_ki_scales_the_integral_term():
    acc = np.tile(np.float32([0, 500, 866]), (1, 1))
    gyro = np.zeros((1, 3), np.float32)
    _, _, _, s1 = run(acc, gyro, settings=MahonySettings(ki=0.1))
    _, _, _, s10 = run(acc, gyro, settings=MahonySettings(ki=1.0))
    # first step from identity: ex = ay/|a|, exInt = ex*KI*dt
    assert s1.int_xyz[0] != 0 and abs(s10.int_xyz[0] / s1.int_xyz[0] - 10.0) < 1e-5


def test_fresh_squares_keeps_the_quaternion_unit():
    gyro = np.tile(np.float32([1000, 2000, 4000]), (100, 1))
    stale = run(np.zeros((100, 3)), gyro)[0][-1].astype(np.float64)
    fresh = run(np.zeros((100, 3)), gyro, settings=MahonySettings(variant="ST 221117"))[0][-1].astype(np.float64)
    assert abs(np.linalg.norm(stale) - 0.9983) < 5e-4
    assert abs(np.linalg.norm(fresh) - 1.0) < 2e-3


def test_dt_sets_the_integration_period():
    n = 200
    gyro = np.tile(np.float32([10000, 0, 0]), (n, 1))  # 10 dps about x (pitch)
    s = MahonySettings(correction=False, variant="ST 221117")
    for dt in (0.00625, 0.00619):
        _, thx, _, _ = run(np.zeros((n, 3)), gyro, settings=MahonySettings(**{**s.__dict__, "dt_s": dt}))
        expected = np.radians(10.0) * n * dt
        assert abs(float(thx[-1]) - expected) < 2e-3 * expected


def test_estimator_options_and_registry():
    est = registry.create("st-mahony", ki=1.0, kp=2.0, correction=False, dt_s=0.005)
    assert est.settings == MahonySettings(ki=1.0, kp_ground=2.0, kp_flight=2.0, correction=False, dt_s=0.005)
    with pytest.raises(ValueError, match="does not take"):
        registry.create("st-mahony", nonsense=1)
    with pytest.raises(ValueError, match="unknown estimator"):
        registry.create("nope")
    est = StMahony()
    est.seed(MahonyState(q_wxyz=(0.0, 1.0, 0.0, 0.0)))
    est.reset()
    assert est.state.bits_equal(MahonyState())
    with pytest.raises(ValueError):
        MahonySettings(ki=float("nan"))
    with pytest.raises(ValueError):
        run(np.zeros((3, 3)), np.zeros((4, 3)))


def test_euler_helpers_agree_with_the_firmware_convention():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    thx, thy, _ = euler_from_quaternion(q)
    fx, fy = quaternion_to_euler(q.astype(np.float32))
    assert np.allclose(thx, fx, atol=2e-6) and np.allclose(thy, fy, atol=5e-3, equal_nan=True)


# --------------------------------------------------------------------------------------------- replay_firmware


def firmware_capture(n: int, seed: int, settings=None):
    """A synthetic capture: 'firmware' outputs from the replica itself (the replica is verified above)."""
    acc, gyro, thr = random_inputs(n, seed)
    q, thx, thy, _ = run(acc, gyro, thr, settings=settings)
    # filter states after every step, as status frames would report them
    states = []
    st = MahonyState()
    for k in range(n):
        _, _, _, st = run(acc[k : k + 1], gyro[k : k + 1], thr[k : k + 1], settings=settings, state=st)
        states.append(st)
    return dict(acc=acc, gyro=gyro, thr=thr.astype(np.int16), q=q, thx=thx, thy=thy, states=states)


def make_telemetry(cap, rows, status_steps, settings=None):
    rows = np.asarray(rows)
    att = SimpleNamespace(
        step=rows.astype(np.int64),
        acc_mg=cap["acc"][rows],
        gyro_mdps=cap["gyro"][rows],
        thr=cap["thr"][rows],
        q_wxyz=cap["q"][rows].copy(),
        thx_rad=cap["thx"][rows].copy(),
        thy_rad=cap["thy"][rows].copy(),
        exact=np.ones(rows.size, bool),
    )
    s = settings or MahonySettings()
    status = np.zeros(len(status_steps), dtype=STATUS_DTYPE)
    for j, k in enumerate(status_steps):
        status[j]["step"] = k
        status[j]["q_wxyz"] = cap["states"][k].q_wxyz
        status[j]["int_xyz"] = cap["states"][k].int_xyz
        status[j]["kp_ground"], status[j]["kp_flight"] = s.kp_ground, s.kp_flight
        status[j]["ki"], status[j]["dt_s"], status[j]["min_thr"] = s.ki, s.dt_s, s.min_thr
        status[j]["flags"] = s.flags
    return SimpleNamespace(attitude=att, status=status)


@pytest.fixture(scope="module")
def capture():
    return firmware_capture(1200, seed=11)


def test_replay_from_power_up_is_bit_exact(capture):
    tel = make_telemetry(capture, np.arange(1200), [100, 600])
    rep = replay_firmware(tel)
    assert rep.seeded.all() and rep.bit_exact.all() and rep.first_mismatch is None and rep.all_exact
    assert [s.source for s in rep.seeds] == ["power-up"]


def test_replay_mid_flight_and_after_gaps_reseeds_from_status(capture):
    rows = np.concatenate([np.arange(300, 700), np.arange(760, 1200)])  # joined at step 300, lost 700..759
    tel = make_telemetry(capture, rows, [250, 400, 720, 900, 1000])
    rep = replay_firmware(tel)
    expect_seeded = ((rows > 400) & (rows < 700)) | (rows > 900)
    assert np.array_equal(rep.seeded, expect_seeded)
    assert np.array_equal(rep.bit_exact, expect_seeded)
    assert np.isnan(rep.q_wxyz[~rep.seeded]).all()
    assert [(s.step, s.source) for s in rep.seeds] == [(401, "status"), (901, "status")]


def test_replay_status_just_before_the_gap_end_seeds_the_first_row(capture):
    rows = np.concatenate([np.arange(0, 500), np.arange(600, 1200)])
    tel = make_telemetry(capture, rows, [599])  # status of step 599 survived, its attitude frame did not
    rep = replay_firmware(tel)
    assert rep.seeded.all() and rep.bit_exact.all()


def test_replay_reports_the_first_mismatch(capture):
    tel = make_telemetry(capture, np.arange(1200), [])
    tel.attitude.q_wxyz[777, 2] = np.nextafter(tel.attitude.q_wxyz[777, 2], np.float32(1))
    rep = replay_firmware(tel)
    assert rep.first_mismatch == 777 and rep.n_bit_exact == 1199 and not rep.all_exact


def test_replay_takes_settings_from_status_frames():
    s = MahonySettings(ki=1.0, correction=False, variant="ST 221117", kp_flight=0.3)
    assert s.flags == FLAG_NO_CORRECTION | FLAG_FRESH_SQUARES
    cap = firmware_capture(600, seed=5, settings=s)
    tel = make_telemetry(cap, np.arange(600), [50], settings=s)
    assert replay_firmware(tel).all_exact
    assert replay_firmware(tel, settings=s).all_exact
    wrong = replay_firmware(tel, settings=MahonySettings())
    assert wrong.first_mismatch == 0


def test_replay_of_encoded_frames_when_the_decoder_exists(capture):
    decoder = pytest.importorskip("steval_link.link.decoder")
    from steval_link.link import protocol

    n = 800
    parts = []
    for k in range(n):
        parts.append(
            protocol.encode_attitude(
                t_us=k * 6190,
                acc_mg=capture["acc"][k],
                gyro_mdps=capture["gyro"][k],
                q_wxyz=capture["q"][k],
                thz_rad=0.0,
                seq=k,
                thr=int(capture["thr"][k]),
            )
        )
        if k in (100, 500):
            st = capture["states"][k]
            parts.append(protocol.encode_status(step=k, t_us=k * 6190, q_wxyz=st.q_wxyz, int_xyz=st.int_xyz))
    stream = b"".join(parts[:200] + parts[260:])  # drop some frames (steps ~199..258)
    tel = decoder.decode_bytes(stream)
    rep = replay_firmware(tel)
    assert rep.first_mismatch is None
    assert rep.seeded[: np.searchsorted(tel.attitude.step, 199)].all()
    assert rep.seeded[np.searchsorted(tel.attitude.step, 501) :].all()
    assert not rep.seeded[np.searchsorted(tel.attitude.step, 300)]


def test_replay_firmware_never_seeds_rounded_text_mode_rows():
    """Text-mode rows are rounded and $STA rows carry no snapshot: nothing is replayed, nothing crashes."""
    from steval_link.link.load import load_telemetry

    tel = load_telemetry(Path(__file__).resolve().parents[1] / "recordings" / "textmode.log")
    assert len(tel.attitude.step) > 100 and not tel.attitude.exact.any()
    rep = firmware_replay.replay_firmware(tel)
    assert rep.n_seeded == 0 and rep.first_mismatch is None
    assert np.isnan(rep.q_wxyz).all()


def test_release_names_map_to_their_filter():
    assert MahonySettings(variant="170318").variant == "ST 170120"
    assert MahonySettings(variant="st-301117 beta").variant == "ST 170120"
    assert MahonySettings(variant="ST 221117").fresh_squares
    with pytest.raises(ValueError, match="no ST release named"):
        MahonySettings(variant="2211")


def test_221117_reads_a_float32_default_as_st_double_literal():
    """A status frame's 0.1f stands for 221117's double literal 0.1; any other value is used as it is given."""
    acc, gyro, thr = random_inputs(600, seed=3)
    exact = run(acc, gyro, thr, settings=MahonySettings(variant="221117"))[0]
    from_status = MahonySettings(variant="221117", ki=float(np.float32(0.1)), dt_s=float(np.float32(0.00625)))
    assert_bits(run(acc, gyro, thr, settings=from_status)[0], exact, "q")
    other = run(acc, gyro, thr, settings=MahonySettings(variant="221117", ki=0.1000001))[0]
    assert not bits_equal(other, exact).all()
