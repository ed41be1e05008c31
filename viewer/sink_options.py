"""The Rerun sink choices of a command (:class:`SinkOptions`) and the checks that need no viewer and no Rerun
import (the ``.rrd``'s folder, URL, ports, display): the CLI checks its options before any work."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import socket
import sys
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from steval_link.errors import ParamError, UserError

DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
#: longest wait to reach the gRPC port of a ``--connect`` URL
CONNECT_TIMEOUT_S = 3.0
#: the ports of a served viewer: SinkOptions field -> what listens there
_PORTS = {"web_port": "web viewer", "grpc_port": "gRPC"}


@dataclass
class SinkOptions:
    """The sink flags of a command. ``connect``: a gRPC URL such as ``rerun+http://127.0.0.1:9876/proxy``;
    ``grpc_port``: the gRPC port of the spawned or served viewer."""

    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    rrd: Path | None = None
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_GRPC_PORT

    @property
    def viewer(self) -> bool:
        """A viewer is chosen (``spawn``, ``serve`` or ``connect``), not only a file."""
        return bool(self.spawn or self.serve or self.connect)

    def any(self) -> bool:
        return bool(self.viewer or self.rrd)


def display_available() -> bool:
    """Whether a desktop viewer window can open (a display on Linux/BSD; always on macOS and Windows)."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def resolve_sinks(options: SinkOptions) -> SinkOptions:
    """With no viewer chosen: ``spawn`` where a display exists, else an ``rrd`` alone (headless), else UserError."""
    if not options.viewer and display_available():
        options.spawn = True
    elif not options.viewer and options.rrd is None:
        raise no_display_error("", "{no_view} to record only")
    return options


def no_display_error(spawn: str, *more_ways: str) -> ParamError:
    """The one sentence for a desktop viewer without a display: the other sinks, then ``more_ways``."""
    ways = ["{rrd} FILE to write a recording", "{serve} for the web viewer", "{connect} URL for a running viewer"]
    ways += more_ways
    text = f"no display for the desktop viewer{spawn}: pass {', '.join(ways[:-1])}, or {ways[-1]}"
    return ParamError(text, "rrd", "serve", "connect", "spawn", "no_view")


def session_sinks(chosen: SinkOptions, *, view: bool) -> SinkOptions | None:
    """A live session's Rerun outputs, resolved and checked once: the chosen or default viewer and the ``.rrd``;
    ``view=False``: the ``.rrd`` alone, None without one (no Rerun at all). UserError when they cannot work."""
    if not view and chosen.rrd is None:
        return None
    chosen = resolve_sinks(chosen) if view else dataclasses.replace(chosen, spawn=False, serve=False, connect=None)
    check_sinks(chosen)
    return chosen


def check_sinks(options: SinkOptions) -> None:
    """Check what can be checked before any work (the ``.rrd``'s folder, URL, ports, display); UserError."""
    if options.rrd is not None:
        check_rrd_path(Path(options.rrd))
    ports = {name: getattr(options, name) for name in _PORTS}
    for name, tcp_port in ports.items():
        if not 1 <= int(tcp_port) <= 65535:
            raise ParamError(f"{{{name}}} must be a TCP port from 1 to 65535, got {tcp_port}", name)
    if options.serve:
        if options.web_port == options.grpc_port:
            raise ParamError(
                f"{{web_port}} and {{grpc_port}} must differ, both are {options.web_port}", "web_port", "grpc_port"
            )
        for name, tcp_port in ports.items():
            if not port_free(tcp_port):
                busy = f"port {tcp_port} for the {_PORTS[name]} is in use on 127.0.0.1"
                fix = f"stop that program or pick another port with {{{name}}} N"
                raise ParamError(f"{busy} (an earlier {{serve}} still running?); {fix}", "serve", name)
    if options.spawn:
        free = port_free(options.grpc_port)
        if not free and not speaks_grpc("127.0.0.1", options.grpc_port, 2.0):
            busy = f"port {options.grpc_port} is in use by a program that is not a Rerun viewer"
            raise ParamError(f"{busy}; pick another port with {{grpc_port}} N", "grpc_port")
        if free and not display_available():  # no viewer there to reuse, and none can open
            raise no_display_error(" ({spawn})")
    if options.connect:
        host, tcp_port = parse_grpc_url(options.connect)
        if not port_open(host, tcp_port, CONNECT_TIMEOUT_S):
            why = f"no Rerun viewer listens at {options.connect}"
            raise ParamError(f"{why}; start one (`rerun`) or use {{spawn}} or {{serve}}", "spawn", "serve")
        plain = options.connect.startswith(("rerun://", "rerun+http://"))
        if plain and not speaks_grpc(host, tcp_port, CONNECT_TIMEOUT_S):
            raise UserError(f"something listens at {options.connect} but it is not a Rerun viewer (no gRPC answer)")


def check_rrd_path(path: Path) -> None:
    """UserError unless ``path`` can be written as a new ``.rrd`` (existing folder, not itself a folder)."""
    if path.is_dir():
        raise UserError(f"cannot write {path}: it is a folder")
    if not path.parent.is_dir():
        raise UserError(f"cannot write {path}: folder {path.parent} does not exist")
    if not os.access(path.parent, os.W_OK):
        raise UserError(f"cannot write {path}: no permission to write in {path.parent}")


def parse_grpc_url(url: str) -> tuple[str, int]:
    """(host, port) of a Rerun gRPC URL such as ``rerun+http://127.0.0.1:9876/proxy``; UserError otherwise."""
    if not url.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        raise ParamError(
            f"{{connect}} needs a Rerun gRPC URL such as rerun+http://127.0.0.1:9876/proxy, got {url!r}", "connect"
        )
    parsed = urllib.parse.urlparse(url)
    tcp_port = None
    with contextlib.suppress(ValueError):
        tcp_port = parsed.port
    if not parsed.hostname:
        raise ParamError(f"{{connect}} URL {url!r} names no host", "connect")
    default = 443 if parsed.scheme == "rerun+https" else DEFAULT_GRPC_PORT
    return parsed.hostname, tcp_port or default


def port_free(tcp_port: int) -> bool:
    """Whether nothing listens on 127.0.0.1:``tcp_port`` (TIME_WAIT connections do not count: servers reuse them)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        if sys.platform != "win32":  # on Windows SO_REUSEADDR would let us bind over a live listener
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", tcp_port))
        except OSError:
            return False
    return True


def port_open(host: str, tcp_port: int, timeout_s: float) -> bool:
    try:
        with socket.create_connection((host, tcp_port), timeout=timeout_s):
            return True
    except OSError:
        return False


#: the HTTP/2 client connection preface and an empty SETTINGS frame (RFC 9113, 3.4 and 6.5)
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


def speaks_grpc(host: str, tcp_port: int, timeout_s: float) -> bool:
    """Whether ``host:tcp_port`` answers our HTTP/2 preface with a SETTINGS frame within ``timeout_s``, as a Rerun
    viewer does (a silent program would make Rerun's gRPC client wait for ever)."""
    try:
        with socket.create_connection((host, tcp_port), timeout=timeout_s) as s:
            s.settimeout(timeout_s)
            s.sendall(_H2_PREFACE)
            head = s.makefile("rb").read(9)  # a frame header; fewer bytes: the peer closed
    except OSError:
        return False
    return len(head) == 9 and head[3] == 0x04  # frame type SETTINGS


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
