"""Helpers the tests share: stream builders, the CLI runners, a fake drone on a pty, a virtual display."""
