"""A model (or any report) as JSON text: numpy values made plain, non-finite ones ``null``.

JSON has no NaN or infinity, and the contract imports no numpy (LinuxCNC's python3), so the
conversion is duck-typed.
"""

from __future__ import annotations

import json
import math
from typing import Any


def jsonable(value: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python (duck-typed, no numpy import), non-finite
    floats to None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return jsonable(value.tolist())  # numpy arrays and scalars
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def dumps(model: dict) -> str:
    return json.dumps(jsonable(model), indent=2, allow_nan=False) + "\n"
