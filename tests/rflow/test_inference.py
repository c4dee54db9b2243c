"""The numpy inference path (rflow.inference) equals the torch model."""

import numpy as np
import pytest
import scipy.linalg
import torch

from rflow.inference import TangentChart
from rflow.manifolds import get_manifold
from rflow.model import ImitationFlow, ModelConfig, RiemannianFlow
from rflow.normalise import Normalisation


CONFIGS = [ModelConfig(layers=11, width=32, hidden_layers=2), ModelConfig(layers=5, width=8, activation="tanh")]


@pytest.fixture(params=CONFIGS)
def model(request):
    torch.manual_seed(0)
    norm = Normalisation(np.array([0.1, -0.2, 0.05]), np.array([0.3, 0.2, 0.1]))
    net = ImitationFlow(3, request.param, norm.goal)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0.0, 0.3)
    return RiemannianFlow("euclidean", np.zeros(3), norm, 0.01, request.param, net)


def torch_step(model, p: np.ndarray) -> np.ndarray:
    net = model.network
    with torch.no_grad():
        q, _ = net.latent(torch.as_tensor(p))
        phi = torch.linalg.matrix_exp(net.dynamics.drift_matrix() * model.dt)
        return net.observe(q @ phi.T)[0].numpy()


def test_batch_inverse_equals_torch(model):
    p = np.random.default_rng(0).normal(size=(1000, 3))
    with torch.no_grad():
        q = model.network.latent(torch.as_tensor(p))[0].numpy()
    assert np.allclose(model.inference.inverse(p), q, atol=1e-6, rtol=0)


def _inverse_in_a_forked_child(model, p, conn):
    conn.send(model.inference.inverse(p))


def test_a_forked_worker_runs_a_large_batch_after_its_parent_ran_it_on_all_cores(model):
    """A batch over PARALLEL_MIN_POINTS runs on all cores here; a forked worker gets the same rows on one core
    (GNU OpenMP, numba's "omp" layer, terminates a forked child that enters a parallel region after its parent)."""
    import multiprocessing

    p = np.random.default_rng(4).normal(size=(model.inference.PARALLEL_MIN_POINTS + 10, 3))
    here = model.inference.inverse(p)
    ours, theirs = multiprocessing.Pipe()
    child = multiprocessing.get_context("fork").Process(target=_inverse_in_a_forked_child, args=(model, p, theirs))
    child.start()
    theirs.close()  # the child's death then ends the pipe at once
    try:
        rows = ours.recv() if ours.poll(60) else None
    except EOFError:
        rows = None
    finally:
        child.join(10)
        if child.is_alive():
            child.kill()
    assert rows is not None and child.exitcode == 0, f"the forked child sent nothing (exit code {child.exitcode})"
    np.testing.assert_array_equal(rows, here)


def test_batch_step_equals_torch(model):
    p = np.random.default_rng(1).normal(size=(300, 3))
    assert np.allclose(model.inference.step(p), torch_step(model, p), atol=1e-6, rtol=0)


def test_single_step_equals_torch(model):
    p = np.random.default_rng(2).normal(size=3)
    assert np.allclose(model.inference.step_single(p), torch_step(model, p[None])[0], atol=1e-6, rtol=0)


def test_latent_path_is_repeated_steps(model):
    net = model.inference
    q0 = np.random.default_rng(3).normal(size=(2, 3))
    path = net.latent_path(q0, 37)
    phi = scipy.linalg.expm(net.drift * model.dt)
    expected = q0.copy()
    for _ in range(37):
        expected = expected @ phi.T
    assert path.shape == (2, 38, 3) and np.allclose(path[:, -1], expected, atol=1e-12)


@pytest.mark.parametrize(
    "name, goal, point",
    [
        ("sphere", np.array([0.5, 0.5, 0.5, 0.5]), np.array([0.0, 0.6, 0.0, 0.8])),
        ("euclidean", np.array([1.0, 2.0]), np.array([0.5, -1.0])),
        ("spd", np.diag([2.0, 3.0]), np.array([[1.0, 0.2], [0.2, 1.5]])),
    ],
)
def test_chart_equals_manifold_maps(name, goal, point):
    manifold = get_manifold(name)
    chart = TangentChart(manifold, goal)
    v = chart.log(point)
    assert np.allclose(v, manifold.log(point, goal), atol=1e-12)
    assert np.allclose(chart.exp(v), manifold.exp(v, goal), atol=1e-12)


@pytest.mark.parametrize("d", [2, 3])
def test_spd_chart_batch_exp_equals_manifold_map(d):
    rng = np.random.default_rng(d)
    a = rng.normal(size=(d, d))
    goal = a @ a.T + np.eye(d)
    v = rng.normal(size=(50, d * (d + 1) // 2))
    v[0] = 0.0
    v[1, d:] = 1e-9  # nearly equal eigenvalues
    manifold = get_manifold("spd")
    chart = TangentChart(manifold, goal)
    assert np.allclose(chart.exp(v), manifold.exp(v, goal), rtol=1e-10, atol=1e-10)
    assert np.allclose(chart.log(chart.exp(v)), v, atol=1e-9)


def test_a_step_that_is_no_positive_number_is_refused_even_where_float_would_take_it(model):
    """float('0.01') and float(True) convert: a string or a bool dt must not find a cached step matrix."""
    from rflow.errors import RFlowError

    net = model.inference
    net.step_matrix(1.0)
    net.step_matrix(0.01)
    for dt in ("0.01", True, "x", [0.01], float("nan"), -0.01):
        with pytest.raises(RFlowError, match="dt="):
            net.step_matrix(dt)
    assert np.array_equal(net.step_matrix(None), net.step_matrix(model.dt))  # None: the default step, as in step()


@pytest.mark.parametrize("steps", [2.5, float("nan"), float("inf"), "5", True, -1])
def test_a_latent_path_length_that_is_no_integer_is_refused_by_name(model, steps):
    from rflow.errors import RFlowError

    with pytest.raises(RFlowError, match="steps="):  # TypeError from np.empty / '<' before
        model.inference.latent_path(np.zeros((1, 3)), steps)


@pytest.mark.parametrize("batch, words", [([[np.nan, 0.0, 0.0]], "NaN or inf"), ([[0.0, np.inf, 0.0]], "NaN or inf"),
                                          ("abc", "not an array of numbers")])
def test_a_flow_input_that_is_no_finite_numbers_is_refused(model, batch, words):
    """forward, inverse and step returned NaN rows for NaN input, and a string raised numpy's ValueError."""
    from rflow.errors import RFlowError

    net = model.inference
    for call in (net.forward, net.inverse, net.step):
        with pytest.raises(RFlowError, match=words):
            call(batch)
