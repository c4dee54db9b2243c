"""Export of demonstrations and evaluation episodes to the LeRobot (v3.0) and robomimic (HDF5) dataset layouts,
and their import as demos: what an episode holds (`features`), the two layouts (`lerobot`, `robomimic`) and the
export folder written under a temporary name (`export_folder`). pyarrow (and pandas) or h5py are imported only when a
layout is used (the `datasets` install extra)."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING

from envs.errors import EnvError

if TYPE_CHECKING:
    from envs.demos.importing import RecordedDemos

__all__ = ["LAYOUTS", "read_dataset", "require_layout"]

#: The dataset layouts.
LAYOUTS: tuple[str, ...] = ("lerobot", "robomimic")


def require_layout(layout: str) -> None:
    """Check that the packages ``layout`` needs are installed (before any long work).

    Raises:
        EnvError: an unknown layout, or its packages missing (naming the install extra).
    """
    needs = {"lerobot": ("pyarrow", "pandas"), "robomimic": ("h5py",)}
    if layout not in needs:
        raise EnvError(f"unknown dataset layout {layout!r} (one of {', '.join(LAYOUTS)})")
    for name in needs[layout]:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError:
            raise EnvError(f"the {layout} format needs {name}: pip install -e '.[datasets]'") from None


def read_dataset(path: str | Path, layout: str) -> RecordedDemos:
    """The demos of a dataset of ``layout`` (a LeRobot folder, or a robomimic .hdf5 or its folder).

    Raises:
        EnvError: an unknown layout, its packages missing, or what the layout's reader raises.
    """
    require_layout(layout)
    if layout == "lerobot":
        from envs.datasets.lerobot import read_lerobot

        return read_lerobot(path)
    from envs.datasets.robomimic import read_robomimic

    return read_robomimic(path)
