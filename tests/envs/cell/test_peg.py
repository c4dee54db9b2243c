"""Tests of envs.cell.peg: the peg model's frame, length and convex prism meshes."""

import mujoco
import numpy as np
import pytest

from envs.cell.contact import ContactConfig
from envs.cell.peg import build_peg, prism_vertices
from envs.cell.shapes import PEG_LENGTH_M, SHAPES


def compiled(shape):
    peg = build_peg(shape, ContactConfig())
    return mujoco.MjModel.from_xml_string(peg.to_xml_string(), peg.get_assets())


@pytest.mark.parametrize("shape", SHAPES)
def test_peg_spans_top_face_to_peg_tip(shape):
    model = compiled(shape)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    aabb = model.geom_aabb[0]  # centre (3), half sizes (3) in the geom frame
    centre_z = data.geom_xpos[0][2] + (data.geom_xmat[0].reshape(3, 3) @ aabb[:3])[2]
    assert np.isclose(centre_z - aabb[5], 0.0, atol=1e-9) and np.isclose(centre_z + aabb[5], PEG_LENGTH_M)


@pytest.mark.parametrize("shape", SHAPES)
def test_peg_tip_site_is_on_the_axis_at_the_peg_length(shape):
    model = compiled(shape)
    assert np.allclose(model.site("peg_tip").pos, [0.0, 0.0, PEG_LENGTH_M])


def test_prism_has_both_end_faces():
    vertices = prism_vertices(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), 2.0)
    assert vertices.shape == (6, 3) and set(vertices[:, 2]) == {0.0, 2.0}
