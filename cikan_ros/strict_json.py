"""Strict JSON (RFC 8259) of the project's results: NaN and infinities written as null, numpy
scalars and arrays as numbers and lists; what any JSON reader parses (``cikan ... --json``,
report's metrics.json, a campaign's summary.json)."""

from __future__ import annotations

import json
import math
from typing import Any


def json_default(obj: Any) -> Any:
    """JSON encoder fallback for numpy scalars and arrays."""
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def dumps(obj: Any, indent: int | None = None) -> str:
    """JSON text (one line unless ``indent``) with NaN/inf written as null."""
    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v
    return json.dumps(clean(json.loads(json.dumps(obj, default=json_default))), allow_nan=False, indent=indent)
