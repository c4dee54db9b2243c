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
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

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
        """
        self.site = site
        self._force = slice(force_adr, force_adr + 3)
        self._torque = slice(torque_adr, torque_adr + 3)
        self._bodies = np.asarray(load.bodies, dtype=int)
        self._masses = model.body_mass[self._bodies].copy()
        self._mass = float(self._masses.sum())
        self._gravity = np.asarray(model.opt.gravity, dtype=np.float64).copy()
        self._weight = -self._mass * self._gravity  # -M g, constant
        self._views: tuple = ()  # (data, its arrays read here), built once per MjData

    def _data_views(self, data: mujoco.MjData) -> tuple:
        """Views of the arrays of ``data`` a reading uses: site rotation (3, 3), site position, body centres of
        mass, force and torque readings (refreshed when another MjData comes)."""
        if not self._views or self._views[0] is not data:
            self._views = (data, data.site_xmat[self.site].reshape(3, 3), data.site_xpos[self.site], data.xipos,
                           data.sensordata[self._force], data.sensordata[self._torque])
        return self._views

    def wrench(self, data: mujoco.MjData) -> FloatArray:
        """[F_ext (N); tau_ext (N m)] (6,) in the sensor frame (a new array).

        With M the carried mass and c its centre of mass: F_0 = -M g, tau_0 = -M (c - s) x g (world), rotated
        into the sensor frame.
        """
        _, rot, site_pos, xipos, force, torque = self._data_views(data)
        lever = self._masses @ xipos[self._bodies] - self._mass * site_pos  # M (c - s)
        gx, gy, gz = self._gravity.tolist()
        lx, ly, lz = lever.tolist()
        out = np.empty(6)
        out[3:] = (-(ly * gz - lz * gy), -(lz * gx - lx * gz), -(lx * gy - ly * gx))  # -(lever x g)
        out[3:] = out[3:] @ rot - torque
        out[:3] = self._weight @ rot - force
        return out


class PegContacts:
    """Normal forces of the environment's contacts on the peg (module docstring)."""

    def __init__(self, model: mujoco.MjModel, peg_geoms: tuple[int, ...], ignored_geoms: tuple[int, ...]) -> None:
        """Args:
            model: the scene (must use the elliptic friction cone).
            peg_geoms: the peg's geoms.
            ignored_geoms: geoms whose contacts with the peg are not the environment's (the fingers).

        Raises:
            EnvError: a pyramidal friction cone (its constraint rows are not normal forces).
        """
        if model.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC:
            raise EnvError("PegContacts needs the elliptic friction cone (ContactConfig.cone='elliptic')")
        peg = np.zeros(model.ngeom, dtype=bool)
        peg[list(peg_geoms)] = True
        ignored = np.zeros(model.ngeom, dtype=bool)
        ignored[list(ignored_geoms)] = True
        # counted[g1, g2]: exactly one of the pair is a peg geom and the other is not ignored (a table built once,
        # so a physics step looks its contacts up in one indexing instead of six array operations)
        one_peg = peg[:, None] != peg[None, :]
        other_ignored = np.where(peg[:, None], ignored[None, :], ignored[:, None])
        self._counted = one_peg & ~other_ignored

    def normal_forces(self, data: mujoco.MjData) -> tuple[float, float]:
        """(sum of normal-force magnitudes, largest single normal force) in N, now."""
        n = data.ncon
        if n == 0:
            return 0.0, 0.0
        contact = data.contact
        geoms = contact.geom
        adr = contact.efc_address[self._counted[geoms[:, 0], geoms[:, 1]]]
        adr = adr[adr >= 0]
        if adr.size == 0:
            return 0.0, 0.0
        forces = np.abs(data.efc_force[adr])
        return float(forces.sum()), float(forces.max())
