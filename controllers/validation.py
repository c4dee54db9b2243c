"""Input checks shared by the controllers: vectors, unit quaternions and sites, each failing with ControllerError."""

from __future__ import annotations

import math
import mujoco
import numpy as np
import numpy.typing as npt

from controllers.errors import ControllerError
from numerics.small_linalg import norm


def as_vector(value: npt.ArrayLike, size: int, name: str) -> npt.NDArray[np.float64]:
    """A finite float64 copy of `value` with `size` entries.

    Raises:
        ControllerError: non-numeric, wrong length or non-finite input (the message names `name`).
    """
    try:
        vector = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as error:
        raise ControllerError(f"{name} must be a numeric vector of length {size}") from error
    if vector.shape != (size,) or not all(map(math.isfinite, vector.tolist())):
        raise ControllerError(f"{name} must be a finite vector of length {size}, got shape {np.shape(value)}")
    return vector


def as_unit_quaternion(value: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
    """`value` as a normalised (w, x, y, z) quaternion; norms outside (0.5, 1.5) are rejected as mistakes.

    Raises:
        ControllerError: not four finite numbers, or far from unit norm.
    """
    quat = as_vector(value, 4, name)
    length = norm(quat)
    if not 0.5 < length < 1.5:
        raise ControllerError(f"{name} must be a unit quaternion (w, x, y, z), got norm {length:.3g}")
    return quat / length


def site_id(model: mujoco.MjModel, site: int | str) -> int:
    """The id of a site given by name or id.

    Raises:
        ControllerError: no such site.
    """
    if isinstance(site, str):
        found = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
        if found < 0:
            raise ControllerError(f"site {site!r} is not in the model")
        return found
    if not 0 <= int(site) < model.nsite:
        raise ControllerError(f"site id {site!r} is out of range [0, {model.nsite})")
    return int(site)


def site_name(model: mujoco.MjModel, site: int | str) -> str:
    """The name of a site given by name or id (mink addresses frames by name).

    Raises:
        ControllerError: no such site, or a site without a name.
    """
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, site_id(model, site))
    if not name:
        raise ControllerError(f"site {site!r} has no name; mink frames are addressed by name")
    return name
