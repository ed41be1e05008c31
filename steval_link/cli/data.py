"""``steval data broad``: BROAD trials (ground truth for ``steval evaluate``) downloaded into the user cache."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import typer

from steval_link.cli.app import argument, option, sub_app
from steval_link.errors import UserError

#: a developer's copy of the trials: ``../shared`` beside the project (editable install)
SHARED_BROAD = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "broad"

data_app = sub_app("data", "Data sets on demand: BROAD trials with optical ground truth.")


_BROAD_HELP = (
    "Download BROAD trials (CC BY 4.0) from the dataset's public repository, check each against its recorded hash, "
    "convert it to the .npz that steval evaluate reads, and say where they are. Trials already there are kept."
)


@data_app.command("broad", help=_BROAD_HELP)
def broad_command(
    trials: argument(
        list[str] | None,
        metavar="TRIALS",
        help="Trials by number (02 7), part of a name (fast_rotation), or all. Default: the six of the accuracy table "
        "(02 07 10 15 24 27).",
    ) = None,
    directory: option(
        Path | None,
        "--dir",
        help="Folder for the .npz trials. Default: the user cache (steval evaluate reads it without DATA).",
    ) = None,
) -> None:
    from steval_link.emulation import broad_fetch as bf  # reason: start-up time

    missing = [module for module in ("pooch", "h5py", "platformdirs") if importlib.util.find_spec(module) is None]
    if missing:
        raise UserError(f'steval data needs {", ".join(missing)}: pip install "steval-link[data]"')
    names = bf.resolve_trials(list(trials or []))
    folder = directory if directory is not None else bf.cache_dir()
    for name in names:
        got = bf.fetch_trial(name, folder)
        how = f"downloaded {got.download_bytes / 1e6:.1f} MB, hash checked" if got.downloaded else "already there"
        typer.echo(f"{name}: {how} -> {got.path}")
    typer.echo(f"{len(names)} BROAD trial(s) in {folder}")
    typer.echo(bf.ATTRIBUTION)


def find_broad_data() -> Path | None:
    """The folder of BROAD trials when none is given: the cache's, else ``../shared``'s; None when neither has any."""
    from steval_link.emulation import broad_fetch as bf  # reason: start-up time

    try:
        cache = bf.cache_dir()
    except ImportError:  # platformdirs is in the data extra
        cache = None
    for folder in (cache, SHARED_BROAD):
        if folder is not None and bf.cached_trials(folder):
            return folder
    return None
