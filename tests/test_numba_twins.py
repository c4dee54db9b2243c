"""Each compiled (numba) twin of a numpy or Python function against its reference, in one pattern.

A twin is registered with the reference it must equal, a draw of inputs, and whether the equality is to the bit
(one Python source compiled twice, e.g. numerics.quaternion's formulas in controllers.impedance_kernel) or to a
tolerance (another algorithm for the same quantity). Add a kernel's twin here when you write one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from controllers import impedance_kernel
from numerics import quaternion


@dataclass(frozen=True)
class Twin:
    """``compiled(*args)`` must equal ``reference(*args)`` for ``args = draw(rng)``: to the bit when ``exact``,
    else to ``atol``."""

    name: str
    compiled: Callable[..., Any]
    reference: Callable[..., Any]
    draw: Callable[[np.random.Generator], tuple[Any, ...]]
    exact: bool = True
    atol: float = 0.0


def _rotation(rng: np.random.Generator) -> np.ndarray:
    """A random rotation matrix; one in four a half turn (trace -1, the z-down tool frames) or a quarter turn
    about an axis (ties on the diagonal), where the branches of the matrix-to-quaternion formula meet."""
    kind = rng.integers(4)
    if kind == 0:
        axis = rng.normal(size=3)
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    if kind == 1:
        return Rotation.from_rotvec(0.5 * np.pi * np.eye(3)[rng.integers(3)]).as_matrix()
    return Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()


def _into(kernel: Callable[..., None], size: int) -> Callable[..., np.ndarray]:
    """A kernel that writes its result into its last argument, called as a function of the others."""
    def call(*args: Any) -> np.ndarray:
        out = np.zeros(size)
        kernel(*args, out)
        return out
    return call


def _pose_error_reference(pos, quat, site_pos, site_mat):
    """[p_d - p; rotvec(q_d conj(q))] with numpy and numerics.quaternion."""
    q = quaternion.mat_to_quat(site_mat.reshape(3, 3))
    rot = quaternion.quat_to_rotvec(quaternion.quat_mul(quat, quaternion.quat_conj(q)))
    return np.concatenate([pos - site_pos, rot])


def _pose_error_compiled(pos, quat, site_pos, site_mat):
    error = np.zeros(6)
    impedance_kernel.pose_error_into(pos, quat, site_pos, site_mat, error, np.zeros(4))
    return error


def _cholesky_compiled(a: np.ndarray) -> np.ndarray:
    c = np.zeros_like(a)
    assert impedance_kernel.cholesky_lower(a, c)
    return c


def _cholesky_draw(rng: np.random.Generator) -> tuple[np.ndarray]:
    a = rng.normal(size=(6, 6))
    return (a @ a.T + 6.0 * np.eye(6),)


TWINS = [
    Twin("hamilton", impedance_kernel.hamilton, quaternion.hamilton, lambda rng: tuple(rng.normal(size=8))),
    Twin("matrix_to_quat_components", impedance_kernel.matrix_to_quat_components,
         quaternion.matrix_to_quat_components, lambda rng: tuple(_rotation(rng).reshape(9))),
    Twin("mat_to_quat_into", _into(impedance_kernel.mat_to_quat_into, 4),
         lambda m: quaternion.mat_to_quat(m.reshape(3, 3)), lambda rng: (_rotation(rng).reshape(9).copy(),)),
    Twin("pose_error_into", _pose_error_compiled, _pose_error_reference,
         lambda rng: (rng.normal(size=3), quaternion.mat_to_quat(_rotation(rng)), rng.normal(size=3),
                      _rotation(rng).reshape(9).copy()), exact=False, atol=1e-12),
    Twin("cholesky_lower", _cholesky_compiled, np.linalg.cholesky, _cholesky_draw, exact=False, atol=1e-12),
    Twin("matrix_components", impedance_kernel.matrix_components,
         lambda *q: quaternion.quat_to_mat(np.array(q)).reshape(9),
         lambda rng: tuple(rng.normal(size=4) * rng.uniform(0.1, 3.0))),
    Twin("quat_of_rotvec_components", impedance_kernel.quat_of_rotvec_components,
         quaternion.quat_of_rotvec_components, lambda rng: tuple(rng.normal(size=3) * rng.uniform(1e-6, 3.0))),
    Twin("rotvec_components", impedance_kernel.rotvec_components, quaternion.rotvec_components,
         lambda rng: tuple(rng.normal(size=4) * rng.uniform(0.1, 3.0))),
]


@pytest.mark.parametrize("twin", TWINS, ids=lambda twin: twin.name)
def test_compiled_twin_equals_its_reference(twin: Twin) -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        args = twin.draw(rng)
        got, want = np.asarray(twin.compiled(*args)), np.asarray(twin.reference(*args))
        if twin.exact:
            assert np.array_equal(got, want), (twin.name, args, got, want)
        else:
            np.testing.assert_allclose(got, want, rtol=0.0, atol=twin.atol, err_msg=twin.name)
