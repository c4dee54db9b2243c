"""Contact parameters of the peg, the sorter and the furniture (one place, applied to their geoms)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # dm_control loads MuJoCo: only the scene builders need it
    from dm_control import mjcf

from envs.errors import EnvError


@dataclass(frozen=True)
class ContactConfig:
    """MuJoCo soft-contact settings for the insertion.

    A MuJoCo contact is a spring-damper on the penetration r: a_ref = -b v - k r with
    k = 1 / (d_max^2 timeconst^2 dampratio^2), b = 2 / (d_max timeconst), and the impedance d(r) in
    [d0, d_max] blends the unconstrained and the reference acceleration, so a resting contact settles at
    about r = (1 - d) a0 / (d k), a0 the acceleration the contact cancels. The defaults (timeconst 2 ms =
    2 timesteps of panda.xml, d = 0.99..0.999) give k = 2.5e5 s^-2 and r < 1e-5 m for a 57 g peg under
    gravity or pushed with 30 N; tests/envs/cell/test_contact_physics.py measures ~1e-7 m resting and ~3e-6 m under
    30 N, far below the 0.1 mm gap of a 0.2 mm clearance. MuJoCo's default contacts (timeconst 20 ms,
    d = 0.9..0.95) let that push sink a square peg 14 mm into the triangle hole.

    Attributes:
        solref: (timeconst s, dampratio); timeconst >= 2 timesteps (1 ms in panda.xml).
        solimp: (d0, d_max, width m, midpoint, power).
        friction: (sliding, torsional, rolling); dry wood/plastic sliding ~0.5.
        margin_m: contact detection margin; 0 so that a peg in a 0.1 mm gap feels no wall it does not touch.
        condim: 3 (sliding friction) or 4 (plus torsional).
        cone: friction cone, "elliptic" (exact Coulomb) or "pyramidal".
        impratio: frictional-to-normal impedance ratio; > 1 stiffens friction against creep.
        multiccd: let the convex collider return several contacts per pair (flat mesh/cylinder faces).
        noslip_iterations: iterations of MuJoCo's no-slip post-solver (``mjOption.noslip_iterations``), which
            removes the creep of soft friction: a contact inside its friction cone does not slide. Without it a
            triangle peg squeezed by the pads (faces at 30 deg to the pads, wedge ratio tan 30 = 0.58 < mu = 1,
            so dry friction holds it) crept 0.44 mm/s out of the grasp, and every grasped peg drifted slowly
            under wall loads; 3 iterations stop both (tests/envs/cell/test_contact_physics.py).
    """

    solref: tuple[float, float] = (0.002, 1.0)
    solimp: tuple[float, float, float, float, float] = (0.99, 0.999, 0.0005, 0.5, 2.0)
    friction: tuple[float, float, float] = (0.5, 0.005, 0.0001)
    margin_m: float = 0.0
    condim: int = 3
    cone: str = "elliptic"
    impratio: float = 10.0
    multiccd: bool = True
    noslip_iterations: int = 3

    def __post_init__(self) -> None:
        if len(self.solref) != 2 or self.solref[0] <= 0.0 or self.solref[1] <= 0.0:
            raise EnvError(f"contact solref={self.solref!r} must be (timeconst > 0, dampratio > 0)")
        d0, dmax, width = self.solimp[0], self.solimp[1], self.solimp[2]
        if len(self.solimp) != 5 or not (0.0 < d0 < 1.0 and 0.0 < dmax < 1.0 and width > 0.0):
            raise EnvError(f"contact solimp={self.solimp!r} must be (d0, dmax in (0, 1), width > 0, mid, power)")
        if len(self.friction) != 3 or min(self.friction) < 0.0:
            raise EnvError(f"contact friction={self.friction!r} must be 3 non-negative coefficients")
        if self.margin_m < 0.0:
            raise EnvError(f"contact margin_m={self.margin_m} must be >= 0")
        if self.condim not in (1, 3, 4, 6):
            raise EnvError(f"contact condim={self.condim} must be 1, 3, 4 or 6")
        if self.cone not in ("elliptic", "pyramidal"):
            raise EnvError(f"contact cone={self.cone!r} must be 'elliptic' or 'pyramidal'")
        if self.impratio < 1.0:
            raise EnvError(f"contact impratio={self.impratio} must be >= 1")
        if not isinstance(self.noslip_iterations, int) or self.noslip_iterations < 0:
            raise EnvError(f"contact noslip_iterations={self.noslip_iterations!r} must be an integer >= 0")

    def geom_attributes(self) -> dict[str, object]:
        """MJCF geom attributes carrying these settings."""
        return {
            "solref": list(self.solref),
            "solimp": list(self.solimp),
            "friction": list(self.friction),
            "margin": self.margin_m,
            "condim": self.condim,
        }

    def apply_options(self, root: mjcf.RootElement) -> None:
        """Set the scene-wide solver options (cone, impratio, no-slip iterations, multiccd) on the root model."""
        root.option.cone = self.cone
        root.option.impratio = self.impratio
        root.option.noslip_iterations = self.noslip_iterations
        if self.multiccd:
            root.option.flag.multiccd = "enable"
