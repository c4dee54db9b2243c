"""What the success check needs to know of one hole of the built scene (`envs.cell.scene.Scene.hole_spec`): its pose,
symmetry, size and cross-section, no MuJoCo."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class HoleSpec:
    """What the scorer needs to know about one hole.

    Attributes:
        shape: the hole's shape name.
        pos: position of the top-opening centre in the world (m).
        quat: orientation (w, x, y, z) of the hole frame, z up out of the hole.
        symmetry_order: k-fold rotational symmetry about the hole axis, 0 for round.
        inradius_m: radius of the largest axis-centred circle inside the hole.
        depth_m: depth of the (blind) hole.
        clearance_m: total clearance between the matching peg and the hole.
        polygon: the hole's counter-clockwise cross-section vertices in the hole frame (m).
        chamfer_m: width of the 45 deg chamfer at the mouth (the straight walls start at z_H = -chamfer).
    """

    shape: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    symmetry_order: int
    inradius_m: float
    depth_m: float
    clearance_m: float
    polygon: tuple[tuple[float, float], ...] = ()
    chamfer_m: float = 0.0
