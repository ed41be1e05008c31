"""The firmware's command receiver in C (firmware_patch/src/stv_cmd.c, host build): its self-tests and fuzz
(``host/test_cmd selftest``), and its decoder against the host's encoder on damaged streams: nothing the host did
not send ever comes out, and every intact command does, in order."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from steval_link.link import protocol as P
from steval_link.link.commands import Command

FW = Path(__file__).resolve().parents[1] / "firmware_patch"

pytestmark = pytest.mark.skipif(
    shutil.which("make") is None or shutil.which("gcc") is None, reason="needs make and gcc for the host build"
)


@pytest.fixture(scope="module")
def test_cmd(tmp_path_factory) -> Path:
    build = tmp_path_factory.mktemp("fw-cmd")
    subprocess.run(
        ["make", "-s", "-C", str(FW), f"BUILD_DIR={build}", f"{build}/host/test_cmd"], check=True, capture_output=True
    )
    return build / "host" / "test_cmd"


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_c_selftest_and_fuzz(test_cmd):
    r = subprocess.run([str(test_cmd), "selftest"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ok ") and "nothing else" in r.stdout


def _decode(test_cmd, data: bytes) -> tuple[list[tuple], str]:
    r = subprocess.run([str(test_cmd), "decode"], input=data, capture_output=True, timeout=60)
    assert r.returncode == 0
    rec = np.frombuffer(r.stdout, dtype=P.COMMAND_DTYPE)
    return [(int(x["cmd_seq"]), int(x["cmd"]), int(x["param"]), float(x["value"])) for x in rec], r.stderr.decode()


def test_c_decoder_takes_exactly_the_python_encoders_commands(test_cmd):
    rng = np.random.default_rng(12)
    stream, intact, sent_any = bytearray(), [], set()
    for seq in range(3000):
        c = Command(int(rng.integers(1, 5)), int(rng.integers(0, 6)), float(np.float32(rng.normal(0, 10))))
        frame = bytearray(c.encode(seq))
        sent_any.add((seq, c.cmd, c.param, float(np.float32(c.value))))
        kind = rng.integers(0, 5)
        if kind == 0:  # intact
            intact.append((seq, c.cmd, c.param, float(np.float32(c.value))))
        elif kind == 1:  # one bit flipped
            bit = int(rng.integers(0, 160))
            frame[bit // 8] ^= 1 << (bit % 8)
        elif kind == 2:  # cut
            frame = frame[: int(rng.integers(1, 19))]
        elif kind == 3:  # noise first
            stream += rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes()
            intact.append((seq, c.cmd, c.param, float(np.float32(c.value))))
        else:  # a drone frame (ack) instead
            frame = bytearray(P.encode_ack(cmd_seq=seq, cmd=c.cmd, result=0, step=seq))
        stream += frame
    got, counts = _decode(test_cmd, bytes(stream))
    assert set(got) <= sent_any  # nothing the host did not send
    # the intact ones come out in order; one may be lost only when a cut frame just before it is completed by its
    # sync byte (a 1/256 chance; the completed frame is then a command the host did send, checked above)
    index = {c: i for i, c in enumerate(got)}
    found = [index[c] for c in intact if c in index]
    assert found == sorted(found) and len(found) >= len(intact) - 3
    assert "rx_bad=" in counts and int(counts.split("rx_bad=")[1]) > 1000
