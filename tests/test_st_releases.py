"""ST's releases by name, end to end: the reference firmware built with each release's filter (make AHRS_VARIANT=...,
our own C), emulated, compared: the replica bit-exact on every step with the release named."""

from __future__ import annotations

import json

import pytest
from support import firmware as S
from support.cli import run_cli, run_steval

pytestmark = pytest.mark.slow


def _elf(tmp_path_factory, *options: str):
    why = S.missing()
    if why:
        pytest.skip(why)
    return S.build_reference(tmp_path_factory.mktemp("ref"), *options)


@pytest.fixture(scope="module", params=["170120", "221117"])
def release_capture(request, tmp_path_factory):
    """(release, capture) of the reference firmware built with that release's filter, 6 s of hand tilts."""
    elf = _elf(tmp_path_factory, f"AHRS_VARIANT={request.param}")
    cap = tmp_path_factory.mktemp("cap") / f"ref{request.param}.stv"
    r = run_steval(["emulate", elf, "--scenario", "hand-tilts", "--duration", "6", "--out", cap, "--no-view"])
    assert r.returncode == 0, r.stderr
    return request.param, cap


def test_each_release_is_bit_exact_and_named(release_capture, monkeypatch, capsys):
    release, cap = release_capture
    code, js, err = run_cli(monkeypatch, capsys, "compare", cap, "--json", "-e", "accel")
    assert code == 0, err
    d = json.loads(js)
    replica = d["replica"]
    assert d["filter"] == f"ST {release}" and replica["all_exact"], replica["diagnosis"]
    assert replica["bit_exact_steps"] == replica["rows"] > 400
    other = next(v for v in replica["variant_bit_exact_steps"] if v != f"ST {release}")
    assert replica["variant_bit_exact_steps"][other] < replica["rows"]
    code, text, _ = run_cli(monkeypatch, capsys, "compare", cap, "-e", "accel")
    assert f"filter: ST {release} (recognised from the firmware ELF's code" in text


def test_a_forced_other_release_says_how_far_it_goes(release_capture, monkeypatch, capsys):
    release, cap = release_capture
    other = "170318" if release == "221117" else "221117"
    code, text, err = run_cli(monkeypatch, capsys, "compare", cap, "--variant", other, "-e", "accel")
    assert code == 0, err
    assert "NOT bit-exact" in text and "(from the --variant): bit-exact on" in text and "leaves the firmware at" in text


def test_the_elf_code_names_the_release(tmp_path_factory):
    """221117's ahrs_fusion_ag calls the double-arithmetic helpers, 170120's none."""
    from steval_link.emulation.elf import Elf
    from steval_link.emulation.symbol_attitude import elf_filter_variant

    for release in ("170120", "221117"):
        variant, why = elf_filter_variant(Elf(_elf(tmp_path_factory, f"AHRS_VARIANT={release}")))
        assert variant == f"ST {release}", why
