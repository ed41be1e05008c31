"""``steval spectrum`` and ``steval_link.analysis.spectrum``: Welch PSD, runs of consecutive steps, aliases, and the
peaks of sinusoids injected into the motion, through the LSM6DSL model and the firmware's ISR pipeline (synth)."""

from __future__ import annotations

import csv
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.cli import run_cli
from support.streams import StreamBuilder

from steval_link import constants as C
from steval_link.analysis import spectrum as S
from steval_link.emulation import motion as M
from steval_link.emulation.synth import SynthOptions, synthesize, write_output
from steval_link.errors import UserError
from steval_link.link.load import load_telemetry

RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"

#: injected sinusoids: (spec, sensor, column, frequency at the sensor)
VIBRATIONS = (
    ("gyro-x:12:3000", "gyro", 0, 12.0),
    ("gyro-y:47:2000", "gyro", 1, 47.0),
    ("gyro-z:100:3000", "gyro", 2, 100.0),  # above the 80.77 Hz Nyquist: 61.54 Hz, and a 416 Hz image at 75.69 Hz
    ("acc-z:25:100", "acc", 5, 25.0),
    ("acc-x:130:200", "acc", 3, 130.0),  # above the Nyquist: at 161.54 - 130 = 31.54 Hz
)


def _synth_capture(path: Path, **kw) -> Path:
    opts = SynthOptions(scenario="bench", duration_s=30.0, seed=5, vibration=tuple(v[0] for v in VIBRATIONS), **kw)
    write_output(synthesize(opts), path)
    return path


@pytest.fixture(scope="module")
def vib_capture(tmp_path_factory) -> Path:
    return _synth_capture(tmp_path_factory.mktemp("spectrum") / "vib.stv")


@pytest.fixture(scope="module")
def vib_spectra(vib_capture):
    return S.compute_spectra(load_telemetry(vib_capture))


# ---- numerics ----------------------------------------------------------------------------------------------------


def test_welch_density_integrates_to_the_variance_and_finds_a_sine():
    rng = np.random.default_rng(1)
    fs = 100.0
    n = 20000
    t = np.arange(n) / fs
    x = 3.0 * rng.standard_normal(n) + 5.0 * np.sin(2 * np.pi * 12.5 * t)
    freq, starts, psd = S.welch_windows(x, fs, 256, 128)
    assert len(starts) == (n - 256) // 128 + 1
    mean = psd.mean(axis=0)[:, 0]
    df = freq[1] - freq[0]
    assert np.sum(mean) * df == pytest.approx(9.0 + 12.5, rel=0.05)  # noise variance + sine power A²/2
    peaks = S.find_peaks(freq, mean, count=1)
    assert abs(peaks[0].freq_hz - 12.5) < df / 2
    assert peaks[0].amplitude == pytest.approx(5.0, rel=0.05)


@pytest.mark.parametrize(
    "f, seen",
    [
        (10.0, 10.0),
        (80.0, 80.0),
        (100.0, C.AHRS_RATE_HZ - 100.0),
        (C.AHRS_RATE_HZ, 0.0),
        (200.0, 200.0 - C.AHRS_RATE_HZ),
        (390.0, 390.0 - 2 * C.AHRS_RATE_HZ),
        (C.ISR_RATE_HZ, 0.0),
    ],
)
def test_alias_hz_folds_into_the_ahrs_band(f, seen):
    assert S.alias_hz(f) == pytest.approx(seen, abs=1e-9)


def test_chain_gain_is_one_at_dc_and_zero_at_multiples_of_the_ahrs_rate():
    assert S.chain_gain(0.0, "acc") == pytest.approx(1.0)
    assert S.chain_gain(0.0, "gyro") == pytest.approx(1.0, abs=1e-3)
    for k in (1, 2, 3, 4):
        assert S.chain_gain(k * C.AHRS_RATE_HZ, "acc") < 1e-9


def test_runs_split_at_drops_restarts_time_jumps_and_nans():
    n = 100
    step = np.arange(n, dtype=np.int64)
    step[40:] += 3  # 3 frames dropped before row 40
    step[70:] -= 500  # a restart at row 70 (step counter goes back)
    t = step / C.AHRS_RATE_HZ
    t[70:] = np.arange(30) / C.AHRS_RATE_HZ + 1000.0
    t[85:] += 0.5  # a time jump at row 85
    v = np.zeros((n, 6))
    v[60] = np.nan
    assert S.contiguous_runs(step, t, v) == [(0, 40), (40, 60), (61, 70), (70, 85), (85, 100)]


def test_throttle_map_separates_what_happens_at_each_throttle():
    """A 20 Hz gyro vibration at throttle 100 and 40 Hz at 600: each throttle bin holds its own peak."""
    n = 4000
    step = np.arange(n)
    t = step / C.AHRS_RATE_HZ
    thr = np.where(step < n // 2, 100, 600).astype(np.int16)
    f = np.where(step < n // 2, 20.0, 40.0)
    gyro = np.zeros((n, 3), np.float32)
    gyro[:, 0] = 1000 * np.sin(2 * np.pi * f * t)
    acc = np.tile(np.array([0, 0, 1000], np.float32), (n, 1))
    tel = SimpleNamespace(attitude=SimpleNamespace(step=step, t_fw_s=t, gyro_mdps=gyro, acc_mg=acc, thr=thr))
    sp = S.compute_spectra(tel, throttle_bins=5)
    assert sp.thr_windows.sum() == len(sp.window_t_fw_s)
    low, high = sp.thr_psd[0, :, 0], sp.thr_psd[-1, :, 0]
    assert abs(sp.freq_hz[np.argmax(low)] - 20.0) <= sp.resolution_hz
    assert abs(sp.freq_hz[np.argmax(high)] - 40.0) <= sp.resolution_hz
    assert sp.thr_windows[1:-1].sum() <= 1  # only the window across the change lies in between


# ---- sinusoids through the sensor model and the ISR pipeline -----------------------------------------------------


def test_parse_vibration():
    v = M.parse_vibration("Gyro-Z:100:3000")
    assert (v.sensor, v.axis, v.freq_hz, v.amplitude) == ("gyro", 2, 100.0, 3000.0)
    assert v.spec == "gyro-z:100:3000"
    for bad in ("gyro:1:2", "gyro-w:1:2", "acc-x:0:5", "acc-x:nan:5", "acc-x:5", "acc-x:5:-1"):
        with pytest.raises(UserError):
            M.parse_vibration(bad)


@pytest.mark.parametrize("spec, sensor, col, f", VIBRATIONS)
def test_injected_sinusoids_peak_at_their_alias_with_the_predicted_amplitude(vib_spectra, spec, sensor, col, f):
    sp = vib_spectra
    amp = M.parse_vibration(spec).amplitude
    main = S.alias_lines(f, sensor, sp.rate_hz)[0]
    expected = S.alias_hz(f)
    assert main.seen_hz == pytest.approx(expected, abs=1e-3)
    peaks = S.find_peaks(sp.freq_hz, sp.psd[:, col], count=3)
    top = peaks[0]
    assert abs(top.freq_hz - expected) <= sp.resolution_hz / 2, (top, expected)
    # the bin holding the peak is the bin of the injected frequency's alias
    assert int(np.argmin(np.abs(sp.freq_hz - top.freq_hz))) == int(np.argmin(np.abs(sp.freq_hz - expected)))
    assert top.amplitude == pytest.approx(amp * main.gain, rel=0.1)


def test_gyro_register_image_lands_where_predicted(vib_spectra):
    """The 100 Hz gyro-z sinusoid also shows through the 416 Hz output register's image (2·416 − 100 Hz)."""
    sp = vib_spectra
    image = [ln for ln in S.alias_lines(100.0, "gyro", sp.rate_hz) if ln.what == "416 Hz ODR image"][0]
    assert image.source_hz == pytest.approx(2 * 416.0 - 100.0)
    peaks = S.find_peaks(sp.freq_hz, sp.psd[:, 2], count=3)
    hit = [p for p in peaks if abs(p.freq_hz - image.seen_hz) <= sp.resolution_hz / 2]
    assert hit and hit[0].amplitude == pytest.approx(3000.0 * image.gain, rel=0.15)


def test_axes_without_injection_show_no_strong_peak(vib_spectra):
    assert S.find_peaks(vib_spectra.freq_hz, vib_spectra.psd[:, 4], count=3, min_db=20.0) == []  # acc y


def test_dropped_frames_split_the_runs_and_the_peaks_stay(tmp_path):
    tel = load_telemetry(_synth_capture(tmp_path / "drops.stv", drop_rate=0.002))
    sp = S.compute_spectra(tel)
    assert tel.stats.frames_missing > 0 and len(sp.runs) > 1 and sp.rows_used <= sp.rows
    top = S.find_peaks(sp.freq_hz, sp.psd[:, 0], count=1)[0]
    assert abs(top.freq_hz - 12.0) <= sp.resolution_hz / 2
    assert any("runs of consecutive rows" in n for n in sp.notes)


@pytest.mark.parametrize("name", ["demo.stv", "midflight_drops.stv", "freefall.stv", "broad_07.stv", "textmode.log"])
def test_bundled_recordings(name):
    tel = load_telemetry(RECORDINGS / name)
    sp = S.compute_spectra(tel)
    assert np.isfinite(sp.psd).all() and (sp.psd >= 0).all()
    assert sp.freq_hz[-1] == pytest.approx(sp.nyquist_hz)
    nominal = C.AHRS_RATE_HZ / sp.decimation
    assert sp.rate_hz == pytest.approx(nominal, rel=0.01)
    if name == "textmode.log":
        assert sp.decimation == 16


# ---- the command -------------------------------------------------------------------------------------------------


def test_cli_summary_csv_and_marks(monkeypatch, capsys, vib_capture, tmp_path):
    out = tmp_path / "s.csv"
    code, stdout, stderr = run_cli(monkeypatch, capsys, "spectrum", vib_capture, "--csv", out, "--mark-hz", "130")
    assert code == 0, stderr
    assert "Nyquist 80.77 Hz" in stdout and "807.7 Hz" in stdout
    gyro_x = [ln for ln in stdout.splitlines() if ln.strip().startswith("gyro x")][0]
    assert gyro_x.split()[3] == "12.00"
    assert "mark 130 Hz (above the Nyquist, aliased)" in stdout and "acc at 31.54 Hz" in stdout
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(S.CSV_COLUMNS)
    psd = [r for r in rows if r["section"] == "psd"]
    f = np.array([float(r["freq_hz"]) for r in psd])
    p = np.array([float(r["acc_x_psd_mg2_per_hz"]) for r in psd])
    assert abs(f[f > 1][np.argmax(p[f > 1])] - (C.AHRS_RATE_HZ - 130.0)) < 0.7
    assert {r["section"] for r in rows} == {"psd", "spectrogram", "throttle"}


@pytest.mark.slow  # matplotlib start-up and a spectrum figure: ≈ 3 s of CPU
def test_cli_plot(monkeypatch, capsys, vib_capture, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "s.png"
    code, stdout, stderr = run_cli(monkeypatch, capsys, "spectrum", vib_capture, "--plot", out, "--mark-hz", "100")
    assert code == 0, stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _one_error_line(code, stdout, stderr) -> str:
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("steval: error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


def test_cli_not_a_capture(monkeypatch, capsys, tmp_path):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    line = _one_error_line(*run_cli(monkeypatch, capsys, "spectrum", junk))
    assert "not a steval capture" in line


def test_cli_no_attitude_frames(monkeypatch, capsys, tmp_path):
    b = StreamBuilder()
    b.text("boot")
    b.status(10)
    b.status(171)
    path = tmp_path / "status_only.bin"
    path.write_bytes(b.bytes())
    line = _one_error_line(*run_cli(monkeypatch, capsys, "spectrum", path))
    assert "no attitude frames" in line


def test_cli_too_short(monkeypatch, capsys, tmp_path):
    b = StreamBuilder()
    for k in range(20):
        b.attitude(k)
    path = tmp_path / "short.bin"
    path.write_bytes(b.bytes())
    line = _one_error_line(*run_cli(monkeypatch, capsys, "spectrum", path))
    assert "too short for a spectrum" in line


@pytest.mark.parametrize(
    "args, words",
    [
        (["--nperseg", "8"], "--nperseg"),
        (["--overlap", "1"], "--overlap"),
        (["--mark-hz", "0"], "--mark-hz"),
        (["--throttle-bins", "0"], "--throttle-bins"),
        (["--csv", "/nonexistent/dir/x.csv"], "does not exist"),
    ],
)
def test_cli_bad_options(monkeypatch, capsys, args, words):
    line = _one_error_line(*run_cli(monkeypatch, capsys, "spectrum", RECORDINGS / "freefall.stv", *args))
    assert words in line


def test_cli_help_names_the_rates(monkeypatch, capsys):
    code, stdout, _ = run_cli(monkeypatch, capsys, "spectrum", "--help")
    assert code == 0
    text = " ".join(stdout.split())
    assert "80.77 Hz" in text and "807.7 Hz" in text and "--mark-hz" in text


def test_cli_missing_file(monkeypatch, capsys, tmp_path):
    line = _one_error_line(*run_cli(monkeypatch, capsys, "spectrum", tmp_path / "nope.stv"))
    assert "no such file" in line


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_cli_rrd_holds_every_spectrum_entity(monkeypatch, capsys, vib_capture, tmp_path):
    from steval_viewer.rrd_check import read_rrd

    rrd = tmp_path / "s.rrd"
    code, stdout, stderr = run_cli(monkeypatch, capsys, "spectrum", vib_capture, "--rrd", rrd, "--mark-hz", "130")
    assert code == 0, stderr
    info = read_rrd(rrd)
    assert info.has_blueprint
    for name, _, _ in S.SIGNALS:
        for kind in ("psd", "spectrogram", "throttle"):
            assert f"spectrum/{kind}/{name}" in info.static
        assert info.samples[f"spectrum/window/{name}"] > 10
    assert "spectrum/notes" in info.static
    assert not list(tmp_path.glob("*.partial"))


@pytest.mark.slow  # synthesises the README's 30 s capture, its spectra and a plot: ≈ 4 s of CPU
def test_readme_example_prints_what_the_readme_says(monkeypatch, capsys, tmp_path):
    """The README's two commands, word for word (in a temporary folder), print the figures it quotes."""
    pytest.importorskip("matplotlib")  # the example draws --plot
    section = (Path(__file__).resolve().parents[1] / "docs" / "howto" / "spectra.md").read_text(encoding="utf-8")
    block = section.split("```sh\n", 1)[1].split("```", 1)[0]
    synth_line, spectrum_line = [ln.split() for ln in block.strip().splitlines()]
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(monkeypatch, capsys, *synth_line[1:])
    assert code == 0, err
    code, out, err = run_cli(monkeypatch, capsys, *spectrum_line[1:])
    assert code == 0, err
    flat = " ".join(out.split())
    for quoted in ("gyro x (mdps) 12.00 Hz 2971.4 mdps", "acc x (mg) 31.54 Hz 47.3 mg", "acc at 31.54 Hz (x0.238)"):
        assert quoted in flat and quoted in " ".join(section.split())
    assert (tmp_path / "vib.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_spawn_opens_the_native_viewer_with_the_spectra(tmp_path):
    """``steval spectrum recordings/demo.stv --spawn`` on a virtual display: the command returns, the viewer stays
    open and holds every spectrum entity; a screenshot shows a rendered window."""
    from support.cli import run_steval
    from support.xdisplay import rerun_processes, screenshot, viewer_port, viewer_recording, virtual_display

    with virtual_display() as display, viewer_port() as port:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        done = run_steval(
            ["spectrum", RECORDINGS / "demo.stv", "--spawn", "--grpc-port", port, "--mark-hz", "390"],
            env=display.env,
            cwd=tmp_path,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
        assert "Traceback" not in done.stderr
        assert rerun_processes(port), "the spawned viewer is not running after the command returned"
        rec = viewer_recording(url, timeline="ahrs_step", end=9209)
        for name, _, _ in S.SIGNALS:
            assert {
                f"/spectrum/psd/{name}",
                f"/spectrum/window/{name}",
                f"/spectrum/spectrogram/{name}",
                f"/spectrum/throttle/{name}",
            } <= rec.entities
        png = screenshot(url, tmp_path / "spectrum.png")
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000


def _panels_and_fonts(fig):
    import matplotlib.text

    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    texts = [t for t in fig.findobj(matplotlib.text.Text) if t.get_visible() and t.get_text().strip()]
    return panels, min(t.get_fontsize() for t in texts)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_figure_has_at_most_nine_readable_panels_and_names_the_register_images(vib_spectra):
    """Nine panels at most, no text under 9 pt; a 12 Hz gyro-x line's register images (36.3 Hz, 60.6 Hz) are
    labelled as its images where they appear; a bench capture (constant throttle) has no throttle map."""
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from steval_link.analysis.spectrum import spectra_figure, throttle_varied

    sp = vib_spectra
    peaks = {name: S.find_peaks(sp.freq_hz, sp.psd[:, k], 4) for k, (name, _, _) in enumerate(S.SIGNALS)}
    fig = spectra_figure(sp, marks_hz=(12.0,), peaks=peaks)
    panels, smallest = _panels_and_fonts(fig)
    assert len(panels) <= 9 and smallest >= 9
    gyro_x = panels[0]
    labels = [t.get_text() for t in gyro_x.texts]
    assert any(t.startswith("36.") and "image of 12.0 Hz" in t for t in labels), labels
    assert not any(t.startswith("12.0") and "image" in t for t in labels)
    assert not throttle_varied(sp)
    assert not any("throttle" in ax.get_title() for ax in panels)
    plt.close(fig)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_figure_of_a_flight_has_the_throttle_map():
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from steval_link.analysis.spectrum import spectra_figure, throttle_varied

    sp = S.compute_spectra(load_telemetry(RECORDINGS / "demo.stv"))
    assert throttle_varied(sp)
    fig = spectra_figure(sp)
    panels, smallest = _panels_and_fonts(fig)
    assert len(panels) == 9 and smallest >= 9
    assert any("vs throttle" in ax.get_title() for ax in panels)
    plt.close(fig)


@pytest.mark.parametrize("f, seen", [(12.0, {12.31, 36.31, 36.62, 60.62})])
def test_register_images_beat_at_24_hz(f, seen):
    lines = S.alias_lines(f, "gyro")
    assert {round(ln.seen_hz, 2) for ln in lines[1:]} == seen
    assert S.REGISTER_BEAT_HZ == pytest.approx(2 * 416 - C.ISR_RATE_HZ)
