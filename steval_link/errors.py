"""The one exception type for user errors: the CLI prints its message as one line and exits with code 2."""


class UserError(Exception):
    """Bad input from the user (missing file, not a capture, wrong option): one clear sentence, exit code 2."""

    exit_code = 2
