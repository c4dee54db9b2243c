"""What the episode measures at the physics rate: the wrist force/torque sensor and the peg's contacts.

Wrist F/T. MuJoCo's ``force``/``torque`` sensors at site ``ft_sensor`` (between flange and hand) read the
wrench F_s, tau_s that the flange exerts on the hand's subtree, in the site frame S. In static equilibrium
    F_s + m g + F_c = 0,   tau_s + r_com x m g + tau_c = 0,
with m the carried mass (hand, fingers and a grasped or welded peg), r_com its centre of mass relative to the
site and F_c, tau_c the wrench the environment exerts on the tool (contacts). The sensor is zeroed for the
tool load like a real F/T sensor, so the reported wrist wrench is the environment's wrench on the tool:
    F_ext = -(F_s - F_0),  tau_ext = -(tau_s - tau_0),  F_0 = -R_S^T m g,  tau_0 = -R_S^T (r_com x m g).
Dynamic loads (m a of the hand when the arm accelerates) remain in it, as on a real sensor.

Contacts. The environment's normal forces on the peg (contacts of peg geoms with anything but the fingers):
their sum of magnitudes (opposing walls add up, they do not cancel) and the largest single one. With an
elliptic friction cone the first row of a contact's constraint force is its normal force.

Both are read every physics step, so their arithmetic is compiled (envs.sensing_kernel).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from envs import sensing_kernel as kernel
from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ToolLoad:
    """Bodies whose weight the wrist sensor carries (hand subtree and, if separate, a grasped peg)."""

    bodies: tuple[int, ...]


class WristSensor:
    """Reads the gravity-compensated wrist wrench (module docstring) from a model's F/T sensor site."""

    def __init__(self, model: mujoco.MjModel, site: int, force_adr: int, torque_adr: int, load: ToolLoad) -> None:
        """Args:
            model: the scene.
            site: the ``ft_sensor`` site id.
            force_adr, torque_adr: the sensors' addresses in ``data.sensordata``.
            load: bodies carried by the sensor (their weight is zeroed out).

        Raises:
            EnvError: a site, sensor address or body that the model does not have, or no body.
        """
        if not 0 <= site < model.nsite:
            raise EnvError(f"WristSensor: site {site} is not one of the model's {model.nsite} sites")
        for name, adr in (("force", force_adr), ("torque", torque_adr)):
            if not 0 <= adr <= model.nsensordata - 3:
                raise EnvError(f"WristSensor: {name} address {adr} leaves no 3 values in the model's "
                               f"{model.nsensordata} sensor values")
        if not load.bodies or not all(0 <= b < model.nbody for b in load.bodies):
            raise EnvError(f"WristSensor: the tool load's bodies {load.bodies} must be 1 or more of the model's "
                           f"{model.nbody} bodies")
        self.site = site
        self._force = slice(force_adr, force_adr + 3)
        self._torque = slice(torque_adr, torque_adr + 3)
        self._bodies = np.asarray(load.bodies, dtype=np.int64)
        masses = model.body_mass[self._bodies]
        gravity = np.asarray(model.opt.gravity, dtype=np.float64)
        self._load = np.concatenate([[float(masses.sum())], gravity, masses])  # [M, g, m_b] (sensing_kernel)
        self._views: tuple = ()  # (data, the kernel's arguments from it), built once per MjData

    def kernel_inputs(self, data: mujoco.MjData) -> tuple:
        """The arguments of ``sensing_kernel.wrist_wrench`` for ``data`` but the output: views of its site
        rotation (9,), site position, body centres of mass and force and torque readings, then the carried bodies
        and [M, g, m_b] (the views are built once per MjData and stay valid for its life)."""
        if not self._views or self._views[0] is not data:
            self._views = (data, data.site_xmat[self.site], data.site_xpos[self.site], data.xipos,
                           data.sensordata[self._force], data.sensordata[self._torque], self._bodies, self._load)
        return self._views[1:]

    def wrench(self, data: mujoco.MjData) -> FloatArray:
        """[F_ext (N); tau_ext (N m)] (6,) in the sensor frame (a new array).

        With M the carried mass and c its centre of mass: F_0 = -M g, tau_0 = -M (c - s) x g (world), rotated
        into the sensor frame.
        """
        out = np.empty(6)
        kernel.wrist_wrench(*self.kernel_inputs(data), out)
        return out


class PegContacts:
    """Normal forces of the environment's contacts on the peg (module docstring)."""

    def __init__(self, model: mujoco.MjModel, peg_geoms: tuple[int, ...], ignored_geoms: tuple[int, ...]) -> None:
        """Args:
            model: the scene (must use the elliptic friction cone).
            peg_geoms: the peg's geoms.
            ignored_geoms: geoms whose contacts with the peg are not the environment's (the fingers).

        Raises:
            EnvError: a pyramidal friction cone (its constraint rows are not normal forces), or a geom that the
                model does not have.
        """
        if model.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC:
            raise EnvError("PegContacts needs the elliptic friction cone (ContactConfig.cone='elliptic')")
        if not all(0 <= g < model.ngeom for g in (*peg_geoms, *ignored_geoms)):
            raise EnvError(f"PegContacts: geoms {peg_geoms} (peg) and {ignored_geoms} (ignored) must be among the "
                           f"model's {model.ngeom} geoms")
        peg = np.zeros(model.ngeom, dtype=bool)
        peg[list(peg_geoms)] = True
        ignored = np.zeros(model.ngeom, dtype=bool)
        ignored[list(ignored_geoms)] = True
        # counted[g1, g2]: exactly one of the pair is a peg geom and the other is not ignored (a table built once,
        # so a physics step looks each contact up in one read)
        one_peg = peg[:, None] != peg[None, :]
        other_ignored = np.where(peg[:, None], ignored[None, :], ignored[:, None])
        self._counted = one_peg & ~other_ignored
        self._scratch = kernel.contact_scratch()

    def kernel_inputs(self) -> tuple[npt.NDArray[np.bool_], FloatArray]:
        """The last arguments of ``sensing_kernel.normal_forces``: the counted-pair table and the forces' buffer."""
        return self._counted, self._scratch

    def normal_forces(self, data: mujoco.MjData) -> tuple[float, float]:
        """(sum of normal-force magnitudes, largest single normal force) in N, now."""
        contact = data.contact
        return kernel.normal_forces(contact.geom, contact.efc_address, data.efc_force, self._counted, self._scratch)
