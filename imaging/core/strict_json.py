"""JSON that every parser reads: no ``NaN`` or ``Infinity``, which Python's ``json`` writes by default and
strict parsers (``JSON.parse``, jq, serde_json) refuse. A value that is not a number is ``null``.

Every JSON sarbot prints or writes (``--json`` output, reports, ``docs/results``, JSON messages on the
live view and in MCAP) goes through :func:`dumps`.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import PurePath
from typing import Any

import numpy as np


def plain(obj: Any) -> Any:
    """``obj`` as plain JSON types: numpy scalars and arrays as numbers and lists, dataclasses as dicts,
    paths as strings, and every float that is NaN or infinite as ``None``.

    Raises
    ------
    TypeError
        For a value JSON has no form for (so a wrong value is not written as its ``repr``).
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (int, np.integer)) and not isinstance(obj, np.bool_):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return plain(dataclasses.asdict(obj))
    if isinstance(obj, PurePath):
        return str(obj)
    raise TypeError(f"no JSON form for {type(obj).__name__}: {obj!r:.80}")


def dumps(obj: Any, **kwargs) -> str:
    """``json.dumps`` of :func:`plain` ``(obj)``; refuses (ValueError) rather than write a non-number."""
    return json.dumps(plain(obj), allow_nan=False, **kwargs)
