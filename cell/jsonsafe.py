"""Plain JSON from numeric results: what ``json.dumps(..., allow_nan=False)`` accepts."""
from __future__ import annotations

import math


def json_safe(obj):
    """JSON-safe copy: non-finite floats become null, tuples lists, numpy scalars and
    0-d arrays Python numbers."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        return json_safe(obj.item())
    return obj
