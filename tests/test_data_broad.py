"""``steval data broad`` against a loopback HTTP server serving tiny HDF5 trials made here: download, hash check,
conversion to the tools' ``.npz``; a cut or altered file is one sentence and leaves nothing in the cache;
``steval evaluate`` without DATA reads the cache, or says in one sentence how to fill it."""

from __future__ import annotations

import http.server
import threading
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

h5py = pytest.importorskip("h5py")
pytest.importorskip("pooch")
pytest.importorskip("platformdirs")

from steval_link.cli import data as cli_data  # noqa: E402
from steval_link.emulation import broad, broad_fetch  # noqa: E402

NAME = "02_undisturbed_slow_rotation_B"
FS = 285.7142857142857


def make_trial_h5(path: Path, n: int = 2400, *, with_quat: bool = True) -> dict[str, np.ndarray]:
    """A BROAD-shaped HDF5 file: a slow tilt about x, still for the first 3 s; returns what it holds."""
    rng = np.random.default_rng(7)
    t = np.arange(n) / FS
    angle = np.where(t > 3.0, 0.3 * np.sin(0.5 * (t - 3.0)), 0.0)
    acc = np.stack([np.zeros(n), 9.81 * np.sin(angle), 9.81 * np.cos(angle)], axis=1) + rng.normal(0, 0.01, (n, 3))
    gyr = np.stack([np.gradient(angle, t), np.zeros(n), np.zeros(n)], axis=1)
    quat = np.stack([np.cos(angle / 2), np.sin(angle / 2), np.zeros(n), np.zeros(n)], axis=1)
    quat[100:110] = np.nan  # markers occluded
    movement = t > 3.0
    with h5py.File(path, "w") as f:
        f["imu_acc"], f["imu_gyr"], f["imu_mag"] = acc, gyr, np.zeros((n, 3))
        if with_quat:
            f["opt_quat"] = quat
        f["movement"] = movement
        f.attrs["sampling_rate"] = FS
    return {"acc": acc, "gyr": gyr, "quat": quat, "movement": movement}


class _Server:
    """Files by URL path on 127.0.0.1; ``cut`` paths announce their whole length but send half and hang up."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}
        self.cut: set[str] = set()
        self.requests: list[str] = []
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802 - the http.server interface
                server.requests.append(self.path)
                body = server.files.get(self.path)
                if body is None:
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body[: len(body) // 2] if self.path in server.cut else body)
                self.close_connection = True

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/broad"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def server(monkeypatch, tmp_path):
    srv = _Server()
    monkeypatch.setenv("STEVAL_BROAD_URL", srv.url)
    monkeypatch.setenv("STEVAL_DATA_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(cli_data, "SHARED_BROAD", tmp_path / "no-shared")
    yield srv
    srv.close()


def _serve(server, monkeypatch, tmp_path, *, registry_bytes: bytes | None = None, **kw) -> dict:
    h5 = tmp_path / "served.hdf5"
    held = make_trial_h5(h5, **kw)
    body = h5.read_bytes()
    server.files[f"/broad/{NAME}.hdf5"] = body
    recorded = broad_fetch.git_blob_sha1(body if registry_bytes is None else registry_bytes)
    monkeypatch.setattr(broad_fetch, "BROAD_FILES", {**broad_fetch.BROAD_FILES, NAME: recorded})
    return held


def _cache(tmp_path) -> Path:
    return tmp_path / "cache" / "broad"


def test_broad_02_downloads_checks_converts_and_attributes(server, monkeypatch, capsys, tmp_path):
    held = _serve(server, monkeypatch, tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "data", "broad", "02")
    assert code == 0, err
    npz = _cache(tmp_path) / f"{NAME}.npz"
    assert str(npz) in out and "hash checked" in out and "CC BY 4.0" in out and "Laidig" in out
    assert sorted(p.name for p in _cache(tmp_path).iterdir()) == [f"{NAME}.npz"]  # nothing else left behind
    trial = broad.load_trial(npz)  # the tools' own loader reads it
    assert trial.fs_hz == pytest.approx(FS)
    assert np.array_equal(trial.acc_mps2, held["acc"].astype(np.float32))
    assert np.array_equal(trial.quat_wxyz, held["quat"].astype(np.float32), equal_nan=True)
    assert np.array_equal(trial.movement, held["movement"])
    # a second run keeps it and asks the server nothing
    before = len(server.requests)
    code, out, _ = run_cli(monkeypatch, capsys, "data", "broad", "2")
    assert code == 0 and "already there" in out and len(server.requests) == before


def test_dir_option_puts_the_trials_there(server, monkeypatch, capsys, tmp_path):
    _serve(server, monkeypatch, tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "data", "broad", "slow_rotation_B", "--dir", tmp_path / "mine")
    assert code == 0, err
    assert (tmp_path / "mine" / f"{NAME}.npz").is_file() and not _cache(tmp_path).exists()


@pytest.mark.parametrize("damage", ["bad-hash", "cut", "not-broad"])
def test_a_broken_download_is_one_sentence_and_leaves_nothing(server, monkeypatch, capsys, tmp_path, damage):
    if damage == "bad-hash":
        _serve(server, monkeypatch, tmp_path, registry_bytes=b"the file as the dataset published it")
    elif damage == "cut":
        _serve(server, monkeypatch, tmp_path)
        server.cut.add(f"/broad/{NAME}.hdf5")
    else:
        _serve(server, monkeypatch, tmp_path, with_quat=False)  # the hash matches what is served
    code, out, err = run_cli(monkeypatch, capsys, "data", "broad", "02")
    assert code == 2
    assert err.startswith("steval: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert NAME in err or "02_" in err
    left = list(_cache(tmp_path).rglob("*")) if _cache(tmp_path).exists() else []
    assert left == []  # no .npz, no partial download, no work folder


def test_unknown_trial_is_one_sentence(server, monkeypatch, capsys):
    code, _, err = run_cli(monkeypatch, capsys, "data", "broad", "99")
    assert code == 2 and "no BROAD trial matches '99'" in err and server.requests == []


def test_the_registry_names_every_trial_once_with_a_git_blob_id():
    names = list(broad_fetch.BROAD_FILES)
    assert len(names) == 39 and [n[:2] for n in names] == [f"{i:02d}" for i in range(1, 40)]
    assert all(len(h) == 40 and int(h, 16) >= 0 for h in broad_fetch.BROAD_FILES.values())
    assert broad_fetch.git_blob_sha1(b"") == "e69de29bb2d1d6434b8b29ae775ad8c2e48c5391"  # git's empty blob


def test_evaluate_with_an_empty_cache_says_how_to_fill_it(server, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "evaluate")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "steval data broad" in err


def test_evaluate_without_data_scores_the_cached_trials(server, monkeypatch, capsys, tmp_path):
    _serve(server, monkeypatch, tmp_path)
    assert run_cli(monkeypatch, capsys, "data", "broad", "02")[0] == 0
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "-e", "accel", "--own-rate")
    assert code == 0, err
    assert "02" in out and "accel" in out
