"""The shape catalogue: peg cross-sections and the holes that match them.

Every peg is a prism of length ``PEG_LENGTH_M`` along its z axis; its cross-section is a convex polygon
given in the peg frame (x, y), centred on the peg axis, except the circle, which is an exact cylinder.

Clearance c is the total play across the hole: every flat face of a hole is c/2 away from the matching
face of a centred peg (hole = peg offset outwards by c/2). For a square that makes the hole side s + c;
for a circle the diameter d + c; for the equilateral triangle the side grows by c*sqrt(3).

The round hole is a regular ``ROUND_HOLE_SEGMENTS``-gon whose inscribed circle has the hole radius, so its
walls are flat boxes and the narrowest gap is exactly c/2.

At the goal the peg_tip frame is the hole frame turned by pi about x (z down instead of up), so the hole
cross-section is the peg cross-section mirrored across the x axis, then offset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from envs.errors import EnvError
from envs.geometry import (
    FloatArray,
    clip_polygon,
    mirror_y,
    offset_convex_polygon,
    rectangle,
    regular_polygon,
)

SHAPES: tuple[str, ...] = ("square", "circle", "triangle", "rectangle", "hexagon")
"""Every peg/hole shape of the sorter; "square" is the default."""

PEG_LENGTH_M: float = 0.09
"""Length of every peg along its axis (top face to peg_tip)."""

ROUND_HOLE_SEGMENTS: int = 32
"""Number of flat wall segments approximating the round hole."""

SQUARE_SIDE_M: float = 0.030
CIRCLE_DIAMETER_M: float = 0.030
TRIANGLE_SIDE_M: float = 0.036
RECTANGLE_SIZE_M: tuple[float, float] = (0.040, 0.020)
HEXAGON_ACROSS_FLATS_M: float = 0.030


@dataclass(frozen=True, eq=False)
class CrossSection:
    """Peg cross-section in the peg frame.

    Attributes:
        shape: name from ``SHAPES``.
        polygon: counter-clockwise convex vertices (n, 2) in metres; for the circle, the inscribed
            ``ROUND_HOLE_SEGMENTS``-gon of the peg radius is given (used only for gripping and plotting).
        radius_m: cylinder radius for the circle, else the polygon's circumradius.
        symmetry_order: k such that a rotation by 360/k deg about the axis maps the shape to itself;
            0 for the circle (any rotation).
    """

    shape: str
    polygon: FloatArray
    radius_m: float
    symmetry_order: int

    @property
    def is_round(self) -> bool:
        """True for the cylinder peg."""
        return self.symmetry_order == 0


def check_shape(shape: str) -> str:
    """Return ``shape`` if it is in ``SHAPES``.

    Raises:
        EnvError: for an unknown shape name.
    """
    if shape not in SHAPES:
        raise EnvError(f"shape={shape!r} is unknown; choose one of {', '.join(SHAPES)}")
    return shape


def peg_cross_section(shape: str) -> CrossSection:
    """Cross-section of the peg of ``shape`` (sizes in the module constants).

    Raises:
        EnvError: for an unknown shape name.
    """
    check_shape(shape)
    if shape == "square":
        half = SQUARE_SIDE_M / 2.0
        polygon = rectangle(-half, half, -half, half)
        return CrossSection(shape, polygon, float(np.hypot(half, half)), 4)
    if shape == "rectangle":
        hx, hy = RECTANGLE_SIZE_M[0] / 2.0, RECTANGLE_SIZE_M[1] / 2.0
        return CrossSection(shape, rectangle(-hx, hx, -hy, hy), float(np.hypot(hx, hy)), 2)
    if shape == "triangle":
        inradius = TRIANGLE_SIDE_M / (2.0 * np.sqrt(3.0))
        polygon = regular_polygon(3, inradius, first_vertex_deg=0.0)
        return CrossSection(shape, polygon, 2.0 * inradius, 3)
    if shape == "hexagon":
        inradius = HEXAGON_ACROSS_FLATS_M / 2.0
        polygon = regular_polygon(6, inradius, first_vertex_deg=0.0)
        return CrossSection(shape, polygon, inradius / np.cos(np.pi / 6.0), 6)
    radius = CIRCLE_DIAMETER_M / 2.0
    inscribed = regular_polygon(ROUND_HOLE_SEGMENTS, radius * np.cos(np.pi / ROUND_HOLE_SEGMENTS))
    return CrossSection(shape, inscribed, radius, 0)


def hole_polygon(shape: str, clearance_m: float) -> FloatArray:
    """Counter-clockwise vertices (n, 2) of the hole of ``shape`` in its hole frame.

    Polygonal pegs: mirror_y(peg polygon) offset outwards by clearance/2.
    Circle: regular ``ROUND_HOLE_SEGMENTS``-gon with inradius r + clearance/2, a flat face facing +x.

    Raises:
        EnvError: for an unknown shape name.
    """
    section = peg_cross_section(shape)
    if section.is_round:
        half_angle_deg = 180.0 / ROUND_HOLE_SEGMENTS
        return regular_polygon(ROUND_HOLE_SEGMENTS, section.radius_m + clearance_m / 2.0, half_angle_deg)
    return offset_convex_polygon(mirror_y(section.polygon), clearance_m / 2.0)


def hole_inradius_m(shape: str, clearance_m: float) -> float:
    """Radius of the largest circle centred on the hole axis inside the hole of ``shape``."""
    polygon = hole_polygon(shape, clearance_m)
    edges = np.roll(polygon, -1, axis=0) - polygon
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / np.linalg.norm(edges, axis=1, keepdims=True)
    return float(np.min(np.einsum("ij,ij->i", normals, polygon)))


def grip_half_width_m(shape: str, pad_half_length_m: float) -> float:
    """Half the opening of two parallel finger pads closing along the peg y axis onto the peg.

    The pads span |x| <= pad_half_length_m; the opening is the widest |y| of the peg inside that slab.
    """
    section = peg_cross_section(shape)
    if section.is_round:
        return section.radius_m
    slab = clip_polygon(section.polygon, np.array([1.0, 0.0]), pad_half_length_m)
    slab = clip_polygon(slab, np.array([-1.0, 0.0]), pad_half_length_m)
    return float(np.max(np.abs(slab[:, 1])))
