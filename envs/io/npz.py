"""Reading a NumPy .npz archive without pickles, refusing any other file first (every reader of .npz files in envs
and scripts).

``np.load`` returns a bare array for a .npy file whatever its name, which is no archive and no context manager, so
a .npy renamed .npz failed deep in the readers with a TypeError. `open_npz` raises ValueError for anything that
is not a zip archive, which the readers already report as one line naming the file.
"""

from __future__ import annotations

import os
import zipfile
from typing import Any

import numpy as np


def open_npz(path: str | os.PathLike[str]) -> Any:
    """``np.load(path, allow_pickle=False)`` of a .npz archive (a context manager, `numpy.lib.npyio.NpzFile`).

    Raises:
        ValueError: the file is not a zip archive (e.g. a .npy file named .npz).
        OSError: it cannot be read.
    """
    if not zipfile.is_zipfile(path):
        raise ValueError("not a .npz archive (a .npy file, or another kind of file?)")
    return np.load(path, allow_pickle=False)


__all__ = ["open_npz"]
