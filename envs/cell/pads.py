"""Compliant finger pads: rubber layers that let a grasped peg turn in the fingers about the closing axis.

Physical model. A pad is a rubber layer of thickness t and shear modulus G bonded to the finger, and the peg's side
face sticks to it (the grasp holds by friction). Turning the face by theta about the layer's normal (the closing
axis) shears the rubber by gamma = r theta / t at distance r from the patch's centre, so the layer resists with

    tau = integral_A G (r theta / t) r dA = (G J_p / t) theta,     J_p = A (a^2 + b^2) / 12

for an a x b contact patch (J_p its polar second moment of area): a torsional spring k = G J_p / t about the
patch's centre. Lateral shear (k_s = G A / t, ~0.5 MN/m per pad) and compression are three orders stiffer than the
arm's compliance and are left rigid. A peg side-loaded by F at distance L from the pads' axis turns in the hand by

    theta = F L / (2 k)                                     (two pads in parallel)

(tests/envs/cell/test_pads.py measures it). The rubber's G follows from its Shore A hardness S by Gent's relation (A. N.
Gent, "On the relation between indentation hardness and Young's modulus", Trans. IRI 34, 1958),
E = 0.0981 (56 + 7.62336 S) / (0.137505 (254 - 2.54 S)) MPa, and G = E / 3 (incompressible rubber).

MuJoCo model. Each pad geom moves into its own body on a hinge about the closing axis through the patch's centre,
with stiffness k, critical damping (``DAMPING_RATIO``) and an armature I_a = k h^2 / 2 (h the timestep). The
armature is numerical, not physical: MuJoCo integrates a joint spring explicitly, and a bare pad (its own inertia
~1e-6 kg m^2) would oscillate unstably at the 1 ms step; with I_a, omega h = h sqrt(k / I) stays below sqrt(2) even
without the peg. At the 67 N m/rad of the realistic preset I_a = 3.4e-5 kg m^2, less than the held square peg's
4.1e-5 kg m^2 per pad about the axis, so the peg's turning is slowed but not stopped (the quasi-static deflection,
what the test measures, does not depend on it). The hinge stops at +-``RANGE_RAD`` (a rubber layer tears or the peg
slips long before).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from envs.errors import EnvError

MAX_STIFFNESS: float = 500.0
"""Largest pad torsional stiffness accepted, N m/rad (stiffer pads are rigid in effect, and their numerical armature
would outweigh the peg: use 0)."""
DAMPING_RATIO: float = 1.0
"""Damping ratio of a pad's turning mode (on the armature alone; ~0.6 with the held peg). The mode's frequency is set
by the numerical armature, so its damping is a numerical choice too: critical, which leaves the quasi-static
compliance (the physical property) unchanged. With zeta = 0.1 or 0.3, a peg side-loaded by 5-10 N set the pads
ringing with a growing amplitude, and at k = 30 N m/rad the peg turned out of the grasp (measured)."""
RANGE_RAD: float = 0.2
"""The pad hinge's travel either way (rad)."""
PAD_MASS_KG: float = 0.002
"""Mass of a rubber pad (a 20 x 54 x 2 mm layer)."""


def check_pad_stiffness(value: Any, name: str = "pad_stiffness_nm_rad") -> float:
    """``value`` if it is a number in [0, MAX_STIFFNESS] N m/rad (0: rigid pads).

    Raises:
        EnvError: otherwise (one line naming it).
    """
    if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and 0.0 <= value <= MAX_STIFFNESS):
        raise EnvError(f"{name}={value!r} must be a number in [0, {MAX_STIFFNESS:g}] N m/rad (0: rigid pads)")
    return float(value)


def shore_a_shear_modulus_pa(shore_a: float) -> float:
    """G = E / 3 with E from Gent's relation for Shore A hardness ``shore_a`` in [20, 90] (module docstring), Pa."""
    if not 20.0 <= shore_a <= 90.0:
        raise EnvError(f"shore_a={shore_a} must lie in [20, 90] (Gent's relation)")
    young_mpa = 0.0981 * (56.0 + 7.62336 * shore_a) / (0.137505 * (254.0 - 2.54 * shore_a))
    return young_mpa * 1e6 / 3.0


def layer_torsion_stiffness(shear_modulus_pa: float, thickness_m: float, width_m: float, length_m: float) -> float:
    """k = G J_p / t, J_p = A (a^2 + b^2) / 12: a bonded a x b rubber layer twisted about its normal, N m/rad."""
    area = width_m * length_m
    return shear_modulus_pa * area * (width_m ** 2 + length_m ** 2) / 12.0 / thickness_m


def pad_patch_m(pad_size: Sequence[float], pad_pos_z_m: float, finger_z_m: float, peg_top_z_m: float,
                peg_length_m: float) -> tuple[float, float, float]:
    """The contact patch of a pad on a peg held at the nominal grasp, in the hand frame: (its width along x, its
    length along z, the z of its centre), from the pad box's half sizes and centre and the peg's span along z."""
    pad_low = finger_z_m + pad_pos_z_m - pad_size[2]
    pad_high = finger_z_m + pad_pos_z_m + pad_size[2]
    low, high = max(pad_low, peg_top_z_m), min(pad_high, peg_top_z_m + peg_length_m)
    if high <= low:
        raise EnvError("the finger pads do not overlap the peg at the nominal grasp")
    return 2.0 * float(pad_size[0]), high - low, 0.5 * (low + high)


def make_pads_compliant(fingers: Sequence[tuple[Any, Any, float]], stiffness_nm_rad: float,
                        patch_centre_z_m: float, timestep_s: float) -> None:
    """Move each finger's pad geom into a body on a torsion hinge about the closing axis (module docstring).

    Args:
        fingers: (finger body, pad geom, +-1 the side) mjcf elements, the pad a child of the finger.
        stiffness_nm_rad: k of each pad, > 0.
        patch_centre_z_m: z of the contact patch's centre in the hand frame (``pad_patch_m``).
        timestep_s: the model's physics timestep h (the armature is k h^2 / 2).
    """
    inertia = 0.5 * stiffness_nm_rad * timestep_s ** 2
    damping = 2.0 * DAMPING_RATIO * math.sqrt(stiffness_nm_rad * inertia)
    for finger, pad, _ in fingers:
        finger_z = float(finger.pos[2])
        pad_pos = np.asarray(pad.pos, dtype=np.float64)
        centre = [0.0, 0.0, patch_centre_z_m - finger_z]
        body = finger.add("body", name=f"{finger.name}_pad_body", pos=centre)
        body.add("inertial", pos=[0.0, float(pad_pos[1]), 0.0], mass=PAD_MASS_KG,
                 diaginertia=[PAD_MASS_KG * 1e-4] * 3)
        body.add("joint", name=f"{finger.name}_pad_hinge", type="hinge", axis=[0.0, 1.0, 0.0],
                 stiffness=stiffness_nm_rad, damping=damping, armature=inertia, range=[-RANGE_RAD, RANGE_RAD])
        attributes = {key: value for key, value in pad.get_attributes().items() if key not in ("name", "pos")}
        pad.remove()
        body.add("geom", name=f"{finger.name}_pad",
                 pos=[float(pad_pos[0]), float(pad_pos[1]), float(pad_pos[2]) - centre[2]], **attributes)
