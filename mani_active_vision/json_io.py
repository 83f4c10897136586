"""JSON the way every tool reads it: NaN and infinities become `null` (Python's `json` writes `NaN`,
which `jq` and most other languages reject)."""

from __future__ import annotations

import json
import math
import os

import numpy as np


def json_safe(data):
    """`data` with non-finite floats as None, numpy scalars and arrays as Python values, tuples as lists."""
    if isinstance(data, dict):
        return {str(k): json_safe(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [json_safe(v) for v in data]
    if isinstance(data, np.ndarray):
        return json_safe(data.tolist())
    if isinstance(data, np.generic):
        data = data.item()
    if isinstance(data, float) and not math.isfinite(data):
        return None
    return data


def save_json(data, path: str) -> None:
    """Write `data` as strict JSON (no NaN) to `path`, creating its folder."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump(json_safe(data), f, indent=2, allow_nan=False)
        f.write("\n")
