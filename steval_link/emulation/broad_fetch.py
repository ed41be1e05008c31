"""BROAD trials on demand: download into a user cache, check, convert to the ``.npz`` that ``broad.load_trial`` reads.

Source: github.com/dlaidig/broad at a pinned commit, ``data_hdf5/NAME.hdf5`` (CC BY 4.0); ``STEVAL_BROAD_URL``
replaces the base URL. Hashes: each file's git blob id at that commit (:data:`BROAD_FILES`), its one published
fingerprint. pooch downloads into a private folder of the cache; only a complete ``.npz`` is renamed into place.
The conversion keeps the values as float32: ``acc`` = ``imu_acc`` (m/s²), ``gyr`` = ``imu_gyr`` (rad/s), ``quat`` =
``opt_quat`` (wxyz, IMU → ENU, NaN where occluded), ``movement`` (bool), ``fs`` = ``sampling_rate`` (Hz).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from steval_link.errors import UserError, printable

BROAD_COMMIT = "7e2f8189bb4a3ac91eae32c69b6bc87f08a6e2ad"  #: the dataset repository's commit the hashes belong to
_DEFAULT_URL = f"https://raw.githubusercontent.com/dlaidig/broad/{BROAD_COMMIT}/data_hdf5"
DEFAULT_TRIALS = ("02", "07", "10", "15", "24", "27")  #: the trials `steval evaluate`'s table and the course use
ATTRIBUTION = (
    'BROAD: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust Inertial Orientation '
    'Estimation", Data 6(7), 2021, doi:10.3390/data6070072; licensed CC BY 4.0 '
    "(https://creativecommons.org/licenses/by/4.0/); converted to float32 .npz, values unchanged."
)

#: trial name → git blob SHA-1 of its ``data_hdf5/NAME.hdf5`` at :data:`BROAD_COMMIT`
BROAD_FILES: dict[str, str] = {
    "01_undisturbed_slow_rotation_A": "88733d048421c890d799c711f320e56c2677d71c",
    "02_undisturbed_slow_rotation_B": "7c1d2112a02cabd2685630c3b6bcc6db2bf2aac7",
    "03_undisturbed_slow_rotation_C": "66b4081d2e29550613e87805bc106425b1c8bf63",
    "04_undisturbed_slow_rotation_with_breaks_A": "52d91e8c92d6cf93ed80bc435fac3f57a863e1d5",
    "05_undisturbed_slow_rotation_with_breaks_B": "93efe3d55d13394b4fd8cd948c9df0e01b3bf400",
    "06_undisturbed_fast_rotation_A": "e9b49cff450a89be509136be7caa6738f9d3a7fa",
    "07_undisturbed_fast_rotation_B": "3fef8390b83c3e28183de921e24d6d335f00af4c",
    "08_undisturbed_fast_rotation_with_breaks_A": "b20a40d6636cbd9005af5468f080e66c44710005",
    "09_undisturbed_fast_rotation_with_breaks_B": "fe69e298477c8ac84263ee18b9090c69a028d297",
    "10_undisturbed_slow_translation_A": "e2327ce7adcce6be270bbf06e9503e0947776cad",
    "11_undisturbed_slow_translation_B": "69c313251d16b3611bf0634783ce3b54f73c1207",
    "12_undisturbed_slow_translation_C": "ad6fc3e72c9c2aae2e4346a5b0935cac63b85b6f",
    "13_undisturbed_slow_translation_with_breaks_A": "629859477a24d639017d396100f7f7c94441a76e",
    "14_undisturbed_slow_translation_with_breaks_B": "39c7f108da5ff05d81e3064ca69b59c8b324ab57",
    "15_undisturbed_fast_translation_A": "439c2baaffd792b090d2f80eb5cad8426d4a5c36",
    "16_undisturbed_fast_translation_B": "7d55a902be48c4130cb5a37adef0dd323ff6ea8e",
    "17_undisturbed_fast_translation_with_breaks_A": "7071a6cbeb03357ead801b2be6020b60a23af11d",
    "18_undisturbed_fast_translation_with_breaks_B": "60d6e04b286fd10f0bb1c701288b040630550c04",
    "19_undisturbed_slow_combined_240s": "3f374fc7b85fff59479553da41b9ff55ddf0c917",
    "20_undisturbed_slow_combined_360s": "5d53dc16eddaea1bbfe990c2e74e022e21e059fa",
    "21_undisturbed_fast_combined": "7169a31f56c53fd7c8d267a654ed1725752b6d61",
    "22_undisturbed_fast_combined_240s": "664964352e9a754d62d693f80f901415411952b7",
    "23_undisturbed_fast_combined_360s": "9186ca7891a517dd199bf7358e17b083f5ccfbd4",
    "24_disturbed_tapping_A": "ab98faba06889ba00303470b043474a7e45ff85b",
    "25_disturbed_tapping_B": "adb99d2a3b76e8d060478766137f743c7f526eaf",
    "26_disturbed_phone_vibration_A": "b45646e375e7d23ef30f53cb847bf61aa980187a",
    "27_disturbed_phone_vibration_B": "7fd217bd1ff9393875e6b7dddcaa0cb6dc44113d",
    "28_disturbed_stationary_magnet_A": "b4e47d6e97019aef4477eb5074947462d5130c6c",
    "29_disturbed_stationary_magnet_B": "2f41d392a2aa3ac0d1bc68ad527e16df05962e8f",
    "30_disturbed_stationary_magnet_C": "11c5320f0ab742ffd7d4f5d3d5d256037ce05cb5",
    "31_disturbed_stationary_magnet_D": "a3795837838e3b3a5725b1fae6a04b2dd52f8ff5",
    "32_disturbed_attached_magnet_1cm": "753ae4c1237bea62c18db4f69d7618ce37253b06",
    "33_disturbed_attached_magnet_2cm": "9e288502f8574b628a743e8ebf1caa7fd85140d1",
    "34_disturbed_attached_magnet_3cm": "a244ea9602d08cfcc11588187ff03097f1b11458",
    "35_disturbed_attached_magnet_4cm": "9d28b565bf7375b0ba98d8dff03131cb8f1acbf5",
    "36_disturbed_attached_magnet_5cm": "f395ad5b8629892d61e4b1c76f4f8a3659792f66",
    "37_disturbed_office_A": "35a91a10bc9c47349ddddced5846ca37b84e7320",
    "38_disturbed_office_B": "8e19af285b120c700991d1a0d1fdc2718430879e",
    "39_disturbed_mixed": "7dae5fe563f45bce818ef41c99343fda943b2e43",
}


@dataclass(frozen=True)
class FetchedTrial:
    """One trial in the cache: its ``.npz`` path, and whether this call downloaded it (False: already there)."""

    name: str
    path: Path
    downloaded: bool
    download_bytes: int


def cache_dir() -> Path:
    """Where downloaded trials live: ``STEVAL_DATA_DIR/broad``, else the user cache's ``steval-link/broad``."""
    root = os.environ.get("STEVAL_DATA_DIR")
    if root:
        return Path(root) / "broad"
    import platformdirs

    return Path(platformdirs.user_cache_dir("steval-link", appauthor=False)) / "broad"


def cached_trials(directory: Path) -> list[Path]:
    """The trial ``.npz`` files in ``directory`` (none when it does not exist), sorted."""
    return sorted(p for p in directory.glob("*.npz") if p.is_file())


def resolve_trials(selectors: list[str]) -> list[str]:
    """Trial names for ``selectors``: a number (``2``, ``02``), part of a name, or ``all``; none: DEFAULT_TRIALS."""
    names = list(BROAD_FILES)
    chosen: list[str] = []
    for sel in selectors or list(DEFAULT_TRIALS):
        if sel.lower() == "all":
            matches = names
        elif sel.isdigit():
            matches = [n for n in names if n.split("_", 1)[0] == f"{int(sel):02d}"]
        else:
            matches = [n for n in names if sel.lower() in n.lower()]
        if not matches:
            raise UserError(
                f"no BROAD trial matches {sel!r}: give a number 01-{len(names):02d}, part of a name, or all"
            )
        chosen.extend(m for m in matches if m not in chosen)
    return chosen


def git_blob_sha1(data: bytes) -> str:
    """Git's object id of ``data`` as a file: SHA-1 of ``b"blob <size>\\0" + data``."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def convert_hdf5(src: Path, dst: Path) -> None:
    """Write BROAD's HDF5 trial ``src`` as the tools' ``.npz`` ``dst``; UserError for a missing or misshapen dataset."""
    import h5py

    try:
        with h5py.File(src, "r") as f:
            arrays = {key: np.asarray(f[h5], dtype=np.float32) for key, h5 in _H5_ARRAYS.items() if h5 in f}
            movement = np.asarray(f["movement"], dtype=bool) if "movement" in f else None
            fs = float(f.attrs.get("sampling_rate", np.nan))
    except OSError as exc:
        raise UserError(f"{src.name} is not a readable HDF5 file ({exc})") from None
    n = movement.shape[0] if movement is not None and movement.ndim == 1 else -1
    for key, width in (("acc", 3), ("gyr", 3), ("quat", 4)):
        if key not in arrays or arrays[key].shape != (n, width):
            raise UserError(f"{src.name} lacks {_H5_ARRAYS[key]} as ({n}, {width}) samples: not a BROAD trial")
    if not (np.isfinite(fs) and fs > 0):
        raise UserError(f"{src.name} has no positive sampling_rate attribute: not a BROAD trial")
    np.savez(dst, acc=arrays["acc"], gyr=arrays["gyr"], quat=arrays["quat"], movement=movement, fs=np.float64(fs))


_H5_ARRAYS = {"acc": "imu_acc", "gyr": "imu_gyr", "quat": "opt_quat"}


def fetch_trial(name: str, directory: Path) -> FetchedTrial:
    """``directory/NAME.npz``, downloaded, checked and converted unless there; a failure leaves nothing of it."""
    expected = BROAD_FILES[name]
    out = directory / f"{name}.npz"
    if out.is_file():
        return FetchedTrial(name, out, False, 0)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        partial = tempfile.TemporaryDirectory(prefix=".partial-", dir=directory, ignore_cleanup_errors=True)
    except OSError as exc:
        raise UserError(f"cannot write the data folder {directory} ({exc.strerror or exc})") from None
    with partial as work:
        hdf5 = _download(f"{os.environ.get('STEVAL_BROAD_URL', _DEFAULT_URL).rstrip('/')}/{name}.hdf5", Path(work))
        data = hdf5.read_bytes()
        got = git_blob_sha1(data)
        if got != expected:
            raise UserError(
                f"BROAD {name}: the download ({len(data)} bytes) does not match its recorded hash "
                f"(git blob {got[:12]}, expected {expected[:12]}), so it was not kept; try again later"
            )
        npz = Path(work) / f"{name}.npz"
        convert_hdf5(hdf5, npz)
        os.replace(npz, out)
        return FetchedTrial(name, out, True, len(data))


def _download(url: str, folder: Path) -> Path:
    """``url`` into ``folder`` with pooch (hash checked by the caller); UserError on any transfer failure."""
    import pooch

    pooch.get_logger().setLevel("WARNING")  # pooch logs each download and the SHA-256 it saw at INFO
    try:
        return Path(pooch.retrieve(url, known_hash=None, fname=url.rsplit("/", 1)[-1], path=folder, progressbar=False))
    except Exception as exc:  # noqa: BLE001 - requests' and urllib3's many transfer errors: one sentence
        raise UserError(f"cannot download {url} ({_reason(exc)}); nothing was kept") from None


def _reason(exc: BaseException) -> str:
    """The innermost message of a transfer error (requests wraps urllib3's, which wraps the socket's)."""
    inner: object = exc
    for _ in range(8):
        nxt = getattr(inner, "reason", None) or (inner.args[0] if getattr(inner, "args", None) else None)
        if not isinstance(nxt, (BaseException, str)) or nxt is inner:
            break
        inner = nxt
    text = str(inner) or type(exc).__name__
    return printable(text.splitlines()[0])[:160]
