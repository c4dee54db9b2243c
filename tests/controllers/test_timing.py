"""The throughput measurements behind `pih bench`."""

import mujoco
import pytest

from assets import PANDA_XML
from controllers.errors import ControllerError
from controllers.timing import measure_control_rate, measure_ik_rate


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(PANDA_XML))


def test_control_rate_ratio_is_closed_over_bare(model):
    rates = measure_control_rate(model, "peg_mount", n_steps=200, repeats=3)
    assert rates["closed_loop_steps_per_s"] > 0 and rates["bare_steps_per_s"] > 0
    assert rates["ratio"] == pytest.approx(rates["closed_loop_steps_per_s"] / rates["bare_steps_per_s"])


def test_closed_loop_is_slower_than_bare_stepping(model):
    assert measure_control_rate(model, "peg_mount", n_steps=500, repeats=3)["ratio"] < 1.0


def test_ik_rate_is_reciprocal_of_median_time(model):
    rates = measure_ik_rate(model, "peg_mount", n_solves=5)
    assert rates["ik_solves_per_s"] == pytest.approx(1e3 / rates["ik_ms_median"])


def test_zero_steps_raise_controller_error(model):
    with pytest.raises(ControllerError, match="n_steps"):
        measure_control_rate(model, n_steps=0)
