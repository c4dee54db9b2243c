"""Conversion of records (dataclasses, numpy arrays and scalars, nested containers) to JSON-ready values, and
the one atomic JSON writer of the project."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import numpy as np


def to_jsonable(value: Any) -> Any:
    """Recursively turn dataclass instances into dicts, tuples into lists, numpy arrays and scalars into Python
    values; dict keys become strings. Anything else is returned unchanged."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_json_atomic(path: str | os.PathLike[str], value: Any, allow_nan: bool = True) -> Path:
    """Write ``value`` as indented JSON to a temporary file beside ``path`` (mode per umask) and rename it into
    place, so a reader never sees half a file and a failure leaves the old file (or none). ``allow_nan=False``:
    strict JSON, a NaN or infinity raises ValueError before anything is written."""
    out = Path(path)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(json.dumps(value, indent=2, allow_nan=allow_nan))
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out
