"""Training configurations as JSON files: what `pih search` writes and `pih train` / `pih lasa --config` read.

Layout (extra top-level keys, such as "source" naming the study that found it, are kept but not read):

    {"format": "pih-rflow-train-config", "version": 1,
     "train_config": {"model": {"layers": 11, "activation": "relu", ...}, "optimizer": "adam", "lr": 0.001, ...},
     "source": {...}}

Fields left out of "train_config" (or "model") take the `TrainConfig` / `ModelConfig` defaults; an unknown
field is an error, so a misspelt hyperparameter never goes unnoticed.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping

from rflow.errors import RFlowError
from rflow.model import ModelConfig
from rflow.train import TrainConfig

FORMAT = "pih-rflow-train-config"
VERSION = 1


def _fields(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def train_config_from_dict(values: Mapping[str, Any], where: str = "config") -> TrainConfig:
    """A TrainConfig from a (partial) dict of its fields, "model" a dict of ModelConfig fields.

    Raises:
        RFlowError: unknown fields, wrong types or values that the configs reject.
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
    try:
        model = ModelConfig(**model_values)
        return TrainConfig(**{**values, "model": model})
    except TypeError as err:
        raise RFlowError(f"{where}: {err}") from None
    except RFlowError as err:
        raise RFlowError(f"{where}: {err}") from None


def load_train_config(path: str | os.PathLike[str]) -> TrainConfig:
    """Read a config file written by `save_train_config`.

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


def save_train_config(path: str | os.PathLike[str], config: TrainConfig,
                      source: Mapping[str, Any] | None = None) -> Path:
    """Write ``config`` (and where it came from) to ``path``: a temporary file beside it, then renamed.

    Raises:
        RFlowError: the folder does not exist.
    """
    out = Path(path)
    if not out.parent.is_dir():
        raise RFlowError(f"cannot write config {out}: folder {out.parent} does not exist")
    record = {"format": FORMAT, "version": VERSION, "train_config": dataclasses.asdict(config),
              "source": dict(source or {})}
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            json.dump(record, handle, indent=2, allow_nan=False)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out
