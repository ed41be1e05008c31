"""``steval`` command line: one module per sub-command, all registered on :data:`steval_link.cli.app.app`."""

from __future__ import annotations

import sys

from steval_link.cli.app import app
from steval_link.errors import UserError

# Each import registers its sub-command(s) on ``app``.
from steval_link.cli import replay as _replay  # noqa: F401,E402
from steval_link.cli import live as _live  # noqa: F401,E402
from steval_link.cli import simulate as _simulate  # noqa: F401,E402
from steval_link.cli import conformance as _conformance  # noqa: F401,E402

__all__ = ["app", "main"]


def main() -> None:
    """Entry point of the ``steval`` console script: user errors become one line on stderr and exit code 2."""
    try:
        app(standalone_mode=False)
    except UserError as exc:
        print(f"steval: error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        print("steval: interrupted", file=sys.stderr)
        sys.exit(130)
