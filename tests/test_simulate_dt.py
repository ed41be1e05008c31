"""``steval simulate --dt`` runs every estimator at the simulation's period (issue #31): ``rate_hz`` = 1/dt for
the estimators that take it, ``dt_s`` for the firmware's filter; the header says the period each one used."""

from __future__ import annotations

import json

import pytest
from support.cli import run_cli

from steval_link.emulation.lab5 import run_simulation


@pytest.mark.parametrize("dt", [0.00625, 0.0125])
def test_ekf3_integrates_at_the_simulations_dt(dt, monkeypatch, capsys):
    args = ["simulate", "-e", "ekf3", "--dt", dt, "--gyro", "0", "0", "20000", "--acc", "0", "0", "1000", "-n", "400"]
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 0, err
    assert out.splitlines()[0].endswith(f"ekf3 integrates at {dt * 1e3:g} ms")
    code, out, err = run_cli(monkeypatch, capsys, *args, "--json")
    rep = json.loads(out)
    assert rep["dt_s"] == dt and rep["estimator_dt_s"] == pytest.approx(dt)
    # 20 dps about z for 400 steps: the yaw integrated with the simulation's dt
    assert rep["final"]["eaz_deg"] == pytest.approx(20.0 * 400 * dt, rel=0.02)


def test_every_estimator_is_told_the_period():
    for name in ("st-mahony", "ekf3", "mekf"):
        res = run_simulation(estimator=name, iterations=10, dt_s=0.01)
        assert res.dt_s == 0.01 and res.estimator_dt_s == pytest.approx(0.01), name
    assert run_simulation(estimator="accel", iterations=3, dt_s=0.01).estimator_dt_s is None  # it does not integrate
    # an option of the user's own wins, and the header says so
    res = run_simulation(estimator="ekf3(rate_hz=100)", iterations=3, dt_s=0.005)
    assert res.estimator_dt_s == pytest.approx(0.01)


def test_the_default_period_is_the_firmwares(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "simulate", "-e", "ekf3", "-n", "5")
    assert code == 0, err
    assert out.splitlines()[0] == "steval simulate: ekf3, 5 iterations of 6.25 ms; ekf3 integrates at 6.25 ms"


def test_two_estimators_are_one_sentence_never_the_last_one(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "simulate", "-e", "ekf3", "-e", "accel", "-n", "3")
    assert code == 2 and "simulate runs one estimator at a time" in err and err.count("\n") == 1
