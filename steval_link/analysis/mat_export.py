"""A decoded capture as a MATLAB ``.mat`` file (``steval export --mat``; needs scipy, extra ``mat``): one struct per
frame type, one column vector per CSV column (units in the names), plus ``settings`` and ``header``. MATLAB::

    S = load('flight.mat');
    plot(S.attitude.t_fw_s, rad2deg(S.attitude.thx_pitch_rad)); disp(S.settings.ki)

float32 stays ``single``, counters integers, flags ``uint8``; missing values are NaN; text a cell array of char."""

from __future__ import annotations

import re
from typing import Any, BinaryIO

import numpy as np

from steval_link.errors import ParamError

INSTALL_HINT = 'pip install "steval-link[mat]"'
#: MATLAB's longest field name.
MAX_NAME = 63


def require_scipy():
    """``scipy.io.savemat``; UserError naming the install command when scipy is missing."""
    try:
        from scipy.io import savemat  # optional package (extra "mat")
    except ImportError:
        raise ParamError(f"{{mat}} needs scipy, which is not installed: {INSTALL_HINT}", "mat") from None
    return savemat


def mat_name(name: str) -> str:
    """A valid MATLAB field name: letters, digits and ``_``, starting with a letter, at most 63 characters."""
    s = re.sub(r"[^0-9A-Za-z_]", "_", str(name))
    if not s or not s[0].isalpha():
        s = "x" + s
    return s[:MAX_NAME]


def _value(v: Any) -> Any:
    """A value as MATLAB takes it: dicts as structs, mixed lists as cell arrays, bool as uint8, None as []."""
    if isinstance(v, dict):
        return {mat_name(k): _value(x) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        return v.astype(np.uint8) if v.dtype == bool else v
    if isinstance(v, bool):
        return np.uint8(v)
    if isinstance(v, (list, tuple)):
        if v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            return np.asarray(v, np.float64)
        cell = np.empty(len(v), dtype=object)
        for i, x in enumerate(v):
            cell[i] = _value(x)
        return cell
    if v is None:
        return np.zeros((0, 0))
    return v


def write_mat(
    tables: dict[str, dict[str, np.ndarray]], settings: dict[str, Any], header: dict[str, Any], out: BinaryIO | str
) -> None:
    """Write ``tables`` (frame type → column → array), ``settings`` and ``header`` as one MATLAB (v5) file ``out``."""
    savemat = require_scipy()
    data = {mat_name(kind): {mat_name(c): _value(np.asarray(v)) for c, v in t.items()} for kind, t in tables.items()}
    data |= {"settings": _value(settings), "header": _value(header)}
    savemat(out, data, appendmat=False, long_field_names=True, do_compression=False, oned_as="column")
