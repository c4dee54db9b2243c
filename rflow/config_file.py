"""Training configurations as JSON files: what `pih search` writes and `pih train` / `pih lasa --config` read.

Layout (extra top-level keys, such as "source" naming the study that found it, are kept but not read):

    {"format": "pih-rflow-train-config", "version": 1,
     "train_config": {"model": {"layers": 11, "activation": "relu", ...}, "optimizer": "adam", "lr": 0.001, ...},
     "source": {...}}

Fields left out of "train_config" (or "model") take the `TrainConfig` / `ModelConfig` defaults; an unknown
field is an error, so a misspelt hyperparameter never goes unnoticed, and so is a value of the wrong type (a
float where the field is an integer, a bool for a number, NaN or infinity) or out of the config's range.
`train_config_record` builds the record; the caller writes it (`pih search`: envs.io.owned_output.write_json, which
adds pih's marker), as rflow writes no command outputs of its own.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import typing
from pathlib import Path
from typing import Any, Mapping

from rflow.errors import RFlowError
from rflow.model import ModelConfig
from rflow.train import TrainConfig

FORMAT = "pih-rflow-train-config"
VERSION = 1


def _fields(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def _typed(value: Any, hint: Any, name: str, where: str) -> Any:
    """``value`` if it has the field's type (int: an integer, not a bool; float: a finite number; str; None
    where the field allows it), a float field's value as float. Raises RFlowError naming the field."""
    allowed = typing.get_args(hint) or (hint,)
    if value is None and type(None) in allowed:
        return None
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if int in allowed and number and isinstance(value, int):
        return value
    if float in allowed and number:
        if not math.isfinite(value):
            raise RFlowError(f"{where}: {name} = {value!r} must be a finite number")
        return float(value)
    if str in allowed and isinstance(value, str):
        return value
    kinds = " or ".join({int: "an integer", float: "a number", str: "a string"}.get(t, "null") for t in allowed)
    raise RFlowError(f"{where}: {name} = {json.dumps(value)} must be {kinds}")


def _typed_fields(cls: type, values: Mapping[str, Any], prefix: str, where: str) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    return {key: _typed(value, hints[key], prefix + key, where) for key, value in values.items()}


def train_config_from_dict(values: Mapping[str, Any], where: str = "config") -> TrainConfig:
    """A TrainConfig from a (partial) dict of its fields, "model" a dict of ModelConfig fields.

    Raises:
        RFlowError: unknown fields, wrong types (module docstring) or values that the configs reject.
    """
    if not isinstance(values, Mapping):
        raise RFlowError(f"{where}: train_config must be a JSON object")
    unknown = set(values) - _fields(TrainConfig)
    model_values = values.get("model", {})
    if not isinstance(model_values, Mapping):
        raise RFlowError(f"{where}: train_config.model must be a JSON object")
    unknown |= {f"model.{key}" for key in set(model_values) - _fields(ModelConfig)}
    if unknown:
        raise RFlowError(f"{where}: unknown training config field(s) {', '.join(sorted(unknown))}")
    top = _typed_fields(TrainConfig, {k: v for k, v in values.items() if k != "model"}, "", where)
    try:
        model = ModelConfig(**_typed_fields(ModelConfig, model_values, "model.", where))
        return TrainConfig(**{**top, "model": model})
    except RFlowError as err:
        raise RFlowError(f"{where}: {err}") from None


def load_train_config(path: str | os.PathLike[str]) -> TrainConfig:
    """Read a config file (`train_config_record`, as `pih search` writes it).

    Raises:
        RFlowError: missing or unreadable file, not JSON, another format, or invalid fields.
    """
    file = Path(path)
    try:
        record = json.loads(file.read_text())
    except FileNotFoundError:
        raise RFlowError(f"config file {file} does not exist") from None
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise RFlowError(f"config file {file} is not readable JSON: {err}") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT or "train_config" not in record:
        raise RFlowError(f"config file {file} is not a training config (expected \"format\": \"{FORMAT}\")")
    if record.get("version") != VERSION:
        raise RFlowError(f"config file {file} has version {record.get('version')!r}; this program reads {VERSION}")
    return train_config_from_dict(record["train_config"], f"config file {file}")


def train_config_record(config: TrainConfig, source: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The config file's record of ``config`` and where it came from (module docstring)."""
    return {"format": FORMAT, "version": VERSION, "train_config": dataclasses.asdict(config),
            "source": dict(source or {})}
