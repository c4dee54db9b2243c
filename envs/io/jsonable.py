"""Conversion of records (dataclasses, numpy arrays and scalars, nested containers) to JSON-ready values (the
writer, strict and atomic, is envs.io.owned_output.write_json)."""

from __future__ import annotations

import dataclasses
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

