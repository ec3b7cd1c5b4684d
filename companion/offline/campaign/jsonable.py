"""Plain JSON values from the campaign's typed records (one conversion for every record)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any


def to_jsonable(obj: Any) -> Any:
    """``obj`` as dicts, lists and scalars: dataclasses by field (fields whose metadata says
    ``json=False`` left out), tuples as lists, non-finite floats as ``None`` (strict JSON has
    no inf or NaN). Other values pass through (numpy scalars: ``json.dumps(default=float)``).
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if f.metadata.get("json", True)}
    if isinstance(obj, dict):
        return {k: to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
