"""The peg: one MJCF model per shape, attached to the hand (held) or to the world (free).

Peg frame: origin at the centre of the top face (where the hand's ``peg_mount`` site sits), z along the
peg axis pointing away from the flange, so the site ``peg_tip`` at z = PEG_LENGTH_M is the centre of the
bottom face with the same axes. The square and rectangle are boxes, the circle a cylinder, the triangle
and hexagon convex mesh prisms whose vertices are computed here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from envs.cell.contact import ContactConfig
from envs.cell.shapes import PEG_LENGTH_M, peg_cross_section
from envs.errors import EnvError

if TYPE_CHECKING:  # loads MuJoCo: imported where the model is built
    from dm_control import mjcf

PEG_MODES: tuple[str, ...] = ("grasped", "welded", "free")
"""How the peg is held: by the fingers' friction, rigidly in the hand, or lying free."""
FRANKA_GRASP_FORCE_N: float = 70.0
"""Continuous grasp force of the Franka hand."""
MAX_GRASP_FORCE_N: float = 2.0 * FRANKA_GRASP_FORCE_N


def check_grasp_force(grasp_force_n: float) -> float:
    """Return ``grasp_force_n`` if it lies in (0, MAX_GRASP_FORCE_N] N.

    Raises:
        EnvError: otherwise.
    """
    if not (isinstance(grasp_force_n, (int, float)) and np.isfinite(grasp_force_n)
            and 0.0 < grasp_force_n <= MAX_GRASP_FORCE_N):
        raise EnvError(f"grasp_force_n={grasp_force_n} must lie in (0, {MAX_GRASP_FORCE_N:g}] N")
    return float(grasp_force_n)

PEG_DENSITY_KG_M3: float = 700.0
"""Hard wood; the 30 mm square peg weighs 57 g."""

PEG_RGBA: dict[str, tuple[float, float, float, float]] = {
    "square": (0.85, 0.15, 0.15, 1.0),
    "circle": (0.15, 0.35, 0.85, 1.0),
    "triangle": (0.95, 0.75, 0.10, 1.0),
    "rectangle": (0.20, 0.65, 0.25, 1.0),
    "hexagon": (0.60, 0.25, 0.70, 1.0),
}


def prism_vertices(polygon: np.ndarray, length_m: float) -> np.ndarray:
    """Vertices (2n, 3) of the prism over ``polygon`` from z = 0 (top face) to z = length_m (peg_tip face)."""
    n = len(polygon)
    top = np.column_stack([polygon, np.zeros(n)])
    bottom = np.column_stack([polygon, np.full(n, length_m)])
    return np.vstack([top, bottom])


def build_peg(shape: str, contact: ContactConfig, length_m: float = PEG_LENGTH_M) -> mjcf.RootElement:
    """MJCF model "peg" of ``shape``: its geoms in the model's worldbody and the site ``peg_tip``.

    Attached to a site or to a frame, the geoms belong to the attachment body, so the scene decides
    whether the peg is held rigidly or floats with a free joint.

    Raises:
        EnvError: for an unknown shape name.
    """
    section = peg_cross_section(shape)
    from dm_control import mjcf

    peg = mjcf.RootElement(model="peg")
    common = dict(contact.geom_attributes(), density=PEG_DENSITY_KG_M3, rgba=PEG_RGBA[shape])
    half_length = length_m / 2.0
    if shape in ("square", "rectangle"):
        half_x, half_y = np.max(section.polygon, axis=0)
        peg.worldbody.add(
            "geom", name="body", type="box", size=[half_x, half_y, half_length], pos=[0, 0, half_length], **common
        )
    elif section.is_round:
        peg.worldbody.add(
            "geom", name="body", type="cylinder", size=[section.radius_m, half_length], pos=[0, 0, half_length],
            **common,
        )
    else:
        vertices = prism_vertices(section.polygon, length_m)
        peg.asset.add("mesh", name=f"{shape}_prism", vertex=vertices.reshape(-1))
        peg.worldbody.add("geom", name="body", type="mesh", mesh=f"{shape}_prism", **common)
    peg.worldbody.add("site", name="peg_tip", pos=[0, 0, length_m], size=[0.004], rgba=[1, 1, 0, 1], group=4)
    peg.worldbody.add("site", name="peg_top", pos=[0, 0, 0], size=[0.004], rgba=[1, 0, 1, 1], group=4)
    return peg
