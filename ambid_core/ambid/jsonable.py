"""Plain JSON types from numpy-laden results: one converter for every summary and file ambid writes."""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np


def to_jsonable(x: Any) -> Any:
    """``x`` with numpy scalars and arrays, tuples and paths turned into JSON types.

    Dicts keep their structure (keys become strings), arrays become nested
    lists, NaN and Inf become None (JSON has neither), paths become strings.
    Other objects pass through unchanged, so ``json.dumps`` still refuses them.
    """
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    return x
