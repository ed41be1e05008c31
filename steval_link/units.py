"""Unit conversions of the firmware's units (mdps) to SI and back, each stated once."""

from __future__ import annotations

import math

#: millidegrees per second → rad/s (float64; the firmware's own float32 literal is ``constants.COE_MDPS_TO_RADPS``)
MDPS_TO_RADPS: float = math.pi / 180.0 / 1000.0
#: rad (or rad/s) → millidegrees (mdps)
RAD_TO_MDPS: float = 180.0 / math.pi * 1000.0
