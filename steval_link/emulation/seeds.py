"""The random streams of one emulation seed. ``steval synth`` and ``steval emulate`` draw from the same streams, so
one seed gives both the same scenario moves and the same sensor offsets."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SEED_SALT = 0x5EA1  #: mixed into every seed, so these streams differ from a plain ``default_rng(seed)``


@dataclass(frozen=True)
class RandomStreams:
    """Independent generators of one seed, one per job (spawned in this order)."""

    motion: np.random.Generator  #: the scenario's moves, throttle jitter, motor vibration
    sensor: np.random.Generator  #: the LSM6DSL's offsets and slow gyro drift
    noise: np.random.Generator  #: the sensor's white noise per reading
    fw: np.random.Generator  #: firmware step timing
    drop: np.random.Generator  #: forced frame drops
    host: np.random.Generator  #: host-side read timing
    boot: np.random.Generator  #: the boot text's timing


def random_streams(seed: int) -> RandomStreams:
    """The streams of ``seed``: ``SeedSequence([seed, SEED_SALT])`` spawned into seven generators."""
    return RandomStreams(*(np.random.default_rng(s) for s in np.random.SeedSequence([int(seed), SEED_SALT]).spawn(7)))
