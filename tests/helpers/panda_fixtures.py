"""The Panda of assets/panda.xml as the arm tests see it: its two finger joints removed (the fingers ride on the
hand as in a welded-peg scene), so nq = nv = nu = 7."""

from __future__ import annotations

import mujoco

from assets import PANDA_XML


def arm_spec() -> mujoco.MjSpec:
    """panda.xml as an MjSpec without finger joints; the "home" keyframe cut to the 7 arm joints."""
    spec = mujoco.MjSpec.from_file(str(PANDA_XML))
    for name in ("finger_joint1", "finger_joint2"):
        spec.delete(spec.joint(name))
    for key in spec.keys:
        key.qpos = list(key.qpos)[:7]
    return spec


def arm_model() -> mujoco.MjModel:
    """``arm_spec()`` compiled."""
    return arm_spec().compile()
