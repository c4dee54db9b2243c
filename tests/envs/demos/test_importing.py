"""`pih demos --import`: tool-frame demos recorded elsewhere converted to peg_tip demo files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from envs.cell.scene import nominal_flange_to_peg_tip
from envs.demos.file import GOAL_TOL_M, load_demos
from envs.demos.importing import FRANKA_TCP, parse_tool_offset
from envs.errors import EnvError
from envs.poses import quat_angle_rad, quat_from_rotvec, quat_mul, slerp
from scripts.cli import main

GOAL_POS = np.array([0.675, -0.051, 0.203])
GOAL_QUAT = np.array([0.0, 1.0, 0.0, 0.0])


def rot(q_wxyz: np.ndarray) -> Rotation:
    """scipy rotation of (w, x, y, z) quaternions (scipy orders them x, y, z, w)."""
    return Rotation.from_quat(np.asarray(q_wxyz)[..., [1, 2, 3, 0]])


def wxyz(r: Rotation) -> np.ndarray:
    return r.as_quat()[..., [3, 0, 1, 2]]


OFFSET = (0.01, -0.02, 0.09, *wxyz(Rotation.from_euler("xyz", [10, -20, 35], degrees=True)))
OFFSET_ARG = ",".join(f"{v:.17g}" for v in OFFSET)


def peg_tip_demos(n: int = 3, m: int = 40, end_offsets_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """N smooth peg_tip demos ending at GOAL (+ an optional per-demo end offset)."""
    rng = np.random.default_rng(1)
    s = np.linspace(0.0, 1.0, m)
    pos, quat = [], []
    for i in range(n):
        end = GOAL_POS + (0.0 if end_offsets_m is None else end_offsets_m[i])
        start = GOAL_POS + rng.uniform(-0.1, 0.1, 3)
        pos.append(start + (3 * s**2 - 2 * s**3)[:, None] * (end - start))
        q0 = quat_mul(quat_from_rotvec(rng.uniform(-0.3, 0.3, 3)), GOAL_QUAT)
        quat.append(slerp(q0, GOAL_QUAT, s))
        quat[-1][-1] = GOAL_QUAT
    return np.stack(pos), np.stack(quat)


def to_tool_frame(pos: np.ndarray, quat: np.ndarray, offset: tuple[float, ...], grasp: tuple) -> tuple:
    """T_W^T = T_W^P (T_F^P)^-1 T_F^T with scipy rotations (scalar-first quaternions), independent of envs."""
    r_wp = rot(quat.reshape(-1, 4))
    r_fp = rot(grasp[1])
    r_ft = rot(np.array(offset[3:]))
    r_wf = r_wp * r_fp.inv()
    p_wf = pos.reshape(-1, 3) - r_wf.apply(grasp[0])
    p_wt = p_wf + r_wf.apply(offset[:3])
    q_wt = wxyz(r_wf * r_ft)
    return p_wt.reshape(pos.shape), q_wt.reshape(quat.shape)


def write_npz(path: Path, **arrays: object) -> Path:
    np.savez(path, **arrays)
    return path


@pytest.fixture(scope="module")
def grasp() -> tuple[np.ndarray, np.ndarray]:
    return nominal_flange_to_peg_tip("square")


def run_import(tmp_path: Path, source: Path, *extra: str) -> tuple[int, Path]:
    out = tmp_path / "out" / "demos.npz"
    out.parent.mkdir(exist_ok=True)
    return main(["demos", "--import", str(source), "--out", str(out), *extra]), out


def test_round_trip_recovers_peg_tip_demos(tmp_path: Path, grasp) -> None:
    pos, quat = peg_tip_demos()
    tool_pos, tool_quat = to_tool_frame(pos, quat, OFFSET, grasp)
    source = write_npz(tmp_path / "rec.npz", pos=tool_pos, quat=tool_quat, dt=0.01)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", str(pos.shape[1]))
    assert code == 0
    demos = load_demos(out)
    assert demos.dt == pytest.approx(0.01, rel=1e-12)
    np.testing.assert_allclose(demos.pos, pos, atol=1e-9, rtol=0)
    sign = np.sign(np.sum(demos.quat * quat, axis=-1, keepdims=True))
    np.testing.assert_allclose(demos.quat, sign * quat, atol=1e-9, rtol=0)
    np.testing.assert_allclose(demos.goal_pos, GOAL_POS, atol=1e-9)


def test_franka_tcp_shorthand_is_103_4_mm_along_z_turned_minus_45_deg() -> None:
    offset = parse_tool_offset("franka-tcp")
    np.testing.assert_allclose(offset.pos, [0.0, 0.0, 0.1034])
    expected = wxyz(Rotation.from_euler("z", -45, degrees=True))
    assert quat_angle_rad(offset.quat, expected) < 1e-12
    assert parse_tool_offset(" Franka-TCP ").pos.tolist() == FRANKA_TCP.pos.tolist()


def test_franka_tcp_example_places_the_peg_tip_beyond_the_tcp(tmp_path: Path, grasp) -> None:
    """A TCP pointing straight down: the peg_tip is the TCP moved by R_tcp Rz(45) (p_grasp - p_tcp) (hand math)."""
    m = 10
    tcp_pos = np.linspace([0.5, 0.0, 0.4], [0.6, -0.05, 0.25], m)
    down = Rotation.from_euler("x", 180, degrees=True)
    tcp_quat = np.tile(wxyz(down), (m, 1))
    source = write_npz(tmp_path / "rec.npz", pos=tcp_pos[None], quat=tcp_quat[None])
    code, out = run_import(tmp_path, source, "--tool-offset", "franka-tcp", "--dt-s", "0.002", "--samples", str(m))
    assert code == 0
    demos = load_demos(out)
    rot_ft = Rotation.from_euler("z", -45, degrees=True).as_matrix()
    tool_to_tip = rot_ft.T @ (grasp[0] - np.array([0.0, 0.0, 0.1034]))
    np.testing.assert_allclose(demos.pos[0], tcp_pos + down.as_matrix() @ tool_to_tip, atol=1e-9)
    expected_quat = down * Rotation.from_matrix(rot_ft).inv() * rot(grasp[1])
    assert np.max(quat_angle_rad(demos.quat[0], wxyz(expected_quat))) < 1e-9
    assert demos.config["tool_offset_arg"] == "franka-tcp"
    assert demos.config["source_file"] == str(source.resolve())


def test_ragged_demos_hold_their_last_pose_until_the_longest_ends(tmp_path: Path, grasp) -> None:
    pos, quat = peg_tip_demos(n=2, m=30)
    short = 20  # demo 1 is cut to its first 20 samples, then brought to the goal by its own last samples
    arrays = {}
    for i, m in enumerate((30, short)):
        p, q = to_tool_frame(pos[i, -m:], quat[i, -m:], OFFSET, grasp)
        arrays[f"pos_{i}"], arrays[f"quat_{i}"] = p, q
    source = write_npz(tmp_path / "rec.npz", dt=0.01, **arrays)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", "30")
    assert code == 0
    demos = load_demos(out)
    assert demos.pos.shape == (2, 30, 3) and demos.dt == pytest.approx(0.01)
    np.testing.assert_allclose(demos.pos[0], pos[0], atol=1e-9)
    np.testing.assert_allclose(demos.pos[1, :short], pos[1, -short:], atol=1e-9)
    np.testing.assert_allclose(demos.pos[1, short:], np.tile(GOAL_POS, (30 - short, 1)), atol=1e-9)
    assert demos.config["layout"] == "ragged" and demos.config["input_lengths"] == [30, short]


def test_demos_off_the_common_goal_fail_and_list_their_jumps(tmp_path: Path, grasp, capsys) -> None:
    ends = np.array([[0.001, 0.0, 0.0], [-0.001, 0.0, 0.0], [0.0, 0.0, 0.0]])
    pos, quat = peg_tip_demos(end_offsets_m=ends)
    tool_pos, tool_quat = to_tool_frame(pos, quat, OFFSET, grasp)
    source = write_npz(tmp_path / "rec.npz", pos=tool_pos, quat=tool_quat, dt=0.01)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", "40")
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert err.count("\n") == 1 and "demo 0: 1.000 mm" in err and "demo 1: 1.000 mm" in err and "demo 2" not in err


def test_snap_goal_blends_only_the_last_part_onto_the_common_goal(tmp_path: Path, grasp, capsys) -> None:
    ends = np.array([[0.002, 0.0, 0.0], [-0.002, 0.0, 0.0], [0.0, 0.0, 0.0]])
    pos, quat = peg_tip_demos(m=100, end_offsets_m=ends)
    tool_pos, tool_quat = to_tool_frame(pos, quat, OFFSET, grasp)
    source = write_npz(tmp_path / "rec.npz", pos=tool_pos, quat=tool_quat, dt=0.01)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", "100", "--snap-goal")
    assert code == 0
    printed = capsys.readouterr().out
    assert "demo 0: 100 samples, jump to the common goal 2.0000 mm" in printed
    assert "last 20 % (0.198 s)" in printed
    demos = load_demos(out)
    np.testing.assert_allclose(demos.goal_pos, GOAL_POS, atol=1e-12)
    np.testing.assert_allclose(demos.pos[:, -1], np.tile(GOAL_POS, (3, 1)), atol=GOAL_TOL_M)
    before_blend = int(np.floor(0.8 * 99)) + 1  # samples at s <= 0.8 are untouched
    np.testing.assert_allclose(demos.pos[:, :before_blend], pos[:, :before_blend], atol=1e-9)
    assert np.all(np.linalg.norm(demos.pos[:2, before_blend] - pos[:2, before_blend], axis=-1) > 0.0)
    assert np.max(np.linalg.norm(demos.pos - pos, axis=-1)) <= 0.002 + 1e-9
    assert np.max(np.linalg.norm(np.diff(demos.pos, axis=1), axis=-1)) < 0.002  # no jump at the end
    np.testing.assert_allclose(demos.residual_pos_m, [0.002, 0.002, 0.0], atol=1e-9)
    assert demos.config["snapped"] is True


def test_ends_apart_keeps_the_demos_and_their_mean_goal(tmp_path: Path, grasp, capsys) -> None:
    ends = np.array([[0.002, 0.0, 0.0], [-0.002, 0.001, 0.0], [0.0, 0.0, 0.0]])
    pos, quat = peg_tip_demos(m=100, end_offsets_m=ends)
    tool_pos, tool_quat = to_tool_frame(pos, quat, OFFSET, grasp)
    source = write_npz(tmp_path / "rec.npz", pos=tool_pos, quat=tool_quat, dt=0.01)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", "100", "--ends-apart")
    assert code == 0 and "kept apart: the goal is the demos' mean end" in capsys.readouterr().out
    demos = load_demos(out)
    assert demos.ends_apart and demos.config["ends_apart"] is True
    np.testing.assert_allclose(demos.pos, pos, atol=1e-9)  # nothing blended
    np.testing.assert_allclose(demos.goal_pos, pos[:, -1].mean(axis=0), atol=1e-12)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", "100", "--ends-apart",
                           "--snap-goal", "--overwrite")
    assert code == 2 and "exclude each other" in capsys.readouterr().err


def test_small_quaternion_norm_errors_are_normalised(tmp_path: Path, grasp) -> None:
    pos, quat = peg_tip_demos(n=1)
    tool_pos, tool_quat = to_tool_frame(pos, quat, OFFSET, grasp)
    source = write_npz(tmp_path / "rec.npz", pos=tool_pos, quat=tool_quat * 1.0005, dt=0.01)
    code, out = run_import(tmp_path, source, "--tool-offset", OFFSET_ARG, "--samples", "40")
    assert code == 0
    np.testing.assert_allclose(np.linalg.norm(load_demos(out).quat, axis=-1), 1.0, atol=1e-12)


def test_overwrite_replaces_only_an_earlier_output(tmp_path: Path, grasp) -> None:
    pos, quat = peg_tip_demos(n=1)
    tool_pos, tool_quat = to_tool_frame(pos, quat, OFFSET, grasp)
    source = write_npz(tmp_path / "rec.npz", pos=tool_pos, quat=tool_quat, dt=0.01)
    out = tmp_path / "out" / "demos.npz"
    out.parent.mkdir()
    args = ["--tool-offset", OFFSET_ARG, "--samples", "40"]
    assert run_import(tmp_path, source, *args)[0] == 0
    assert run_import(tmp_path, source, *args)[0] == 2  # without --overwrite
    assert run_import(tmp_path, source, *args, "--overwrite")[0] == 0
    assert load_demos(out).num_demos == 1
    out.write_bytes(b"somebody else's file")
    assert run_import(tmp_path, source, *args, "--overwrite")[0] == 2  # pih did not write it
    assert out.read_bytes() == b"somebody else's file"


def _good(tmp_path: Path) -> dict[str, np.ndarray]:
    pos, quat = peg_tip_demos(n=2, m=10)
    return {"pos": pos, "quat": quat, "dt": np.float64(0.01)}


def _bad_file(tmp_path: Path, case: str) -> Path:
    """An import file with one problem."""
    path = tmp_path / "rec.npz"
    arrays = _good(tmp_path)
    if case == "missing":
        return tmp_path / "nope.npz"
    if case == "not_npz":
        path.write_text("pos,quat\n1,2\n")
        return path
    if case == "pickled":
        np.save(tmp_path / "rec.npy", np.array([{"pos": 1}], dtype=object), allow_pickle=True)
        return tmp_path / "rec.npy"
    if case == "pickled_member":
        arrays["shape"] = np.array([{"a": 1}], dtype=object)
    elif case == "no_dt":
        del arrays["dt"]
    elif case == "file_dt_nan":
        arrays["dt"] = np.float64(np.nan)
    elif case == "file_dt_zero":
        arrays["dt"] = np.float64(0.0)
    elif case == "pos_wrong_shape":
        arrays["pos"] = arrays["pos"][..., :2]
    elif case == "quat_wrong_shape":
        arrays["quat"] = arrays["quat"][:, :5]
    elif case == "nan_pos":
        arrays["pos"][1, 3, 0] = np.nan
    elif case == "nan_quat":
        arrays["quat"][0, 2, 1] = np.nan
    elif case == "non_unit_quat":
        arrays["quat"][0, 4] *= 1.01
    elif case == "one_sample":
        arrays["pos"], arrays["quat"] = arrays["pos"][:, :1], arrays["quat"][:, :1]
    elif case == "no_demos":
        arrays = {"dt": np.float64(0.01), "positions": arrays["pos"]}
    elif case == "both_layouts":
        arrays["pos_0"], arrays["quat_0"] = arrays["pos"][0], arrays["quat"][0]
    elif case == "ragged_gap":
        arrays = {"pos_0": arrays["pos"][0], "quat_0": arrays["quat"][0], "pos_2": arrays["pos"][1],
                  "quat_2": arrays["quat"][1], "dt": arrays["dt"]}
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("case, extra, message", [
    ("missing", [], "not found"),
    ("not_npz", [], "not a readable .npz"),
    ("pickled", [], "not a readable .npz"),
    ("pickled_member", [], "Object arrays"),
    ("no_dt", [], "--dt-s"),
    ("file_dt_nan", [], "dt"),
    ("file_dt_zero", [], "dt"),
    ("pos_wrong_shape", [], "pos"),
    ("quat_wrong_shape", [], "quat"),
    ("nan_pos", [], "NaN"),
    ("nan_quat", [], "NaN"),
    ("non_unit_quat", [], "not unit"),
    ("one_sample", [], "at least 2"),
    ("no_demos", [], "no demos"),
    ("both_layouts", [], "both"),
    ("ragged_gap", [], "without gaps"),
    ("good", ["--dt-s", "0.02"], "differs"),
    ("good", ["--dt-s", "0"], "--dt-s"),
    ("good", ["--dt-s", "-0.01"], "--dt-s"),
    ("good", ["--dt-s", "nan"], "--dt-s"),
    ("good", ["--tool-offset", "0,0,0.1,1,0,0"], "7 finite numbers"),
    ("good", ["--tool-offset", "0,0,x,1,0,0,0"], "7 finite numbers"),
    ("good", ["--tool-offset", "0,0,nan,1,0,0,0"], "7 finite numbers"),
    ("good", ["--tool-offset", "0,0,0.1,0,0,0,0"], "not 1"),
    ("good", ["--tool-offset", "0,0,0.1,0.7071,0,0,0.7071"], "norm 0.99999041"),
    ("good", ["--tool-offset", "franka"], "7 finite numbers"),
    ("good", ["--samples", "1"], "--samples"),
    ("good", ["--shape", "circle", "--check", "3"], "--check"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path: Path, capsys, case: str,
                                                            extra: list[str], message: str) -> None:
    source = _bad_file(tmp_path, case)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    args = ["demos", "--import", str(source), "--out", str(out_dir / "demos.npz"), "--tool-offset", "franka-tcp"]
    assert main(args + extra) == 2
    err = capsys.readouterr().err
    assert err.startswith("pih demos: error: ") and err.count("\n") == 1 and message in err, err
    assert list(out_dir.iterdir()) == []


def test_missing_output_folder_exits_2(tmp_path: Path, capsys) -> None:
    source = _bad_file(tmp_path, "good")
    out = tmp_path / "no_such_dir" / "demos.npz"
    assert main(["demos", "--import", str(source), "--tool-offset", "franka-tcp", "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err and not out.parent.exists()


def test_output_equal_to_the_import_file_is_refused(tmp_path: Path, capsys) -> None:
    source = _bad_file(tmp_path, "good")
    before = source.read_bytes()
    assert main(["demos", "--import", str(source), "--tool-offset", "flange", "--out", str(source),
                 "--overwrite"]) == 2
    assert source.read_bytes() == before


def test_shape_in_the_file_must_match_the_flag(tmp_path: Path, capsys) -> None:
    arrays = _good(tmp_path)
    source = write_npz(tmp_path / "rec.npz", shape=np.str_("circle"), **arrays)
    code, out = run_import(tmp_path, source, "--tool-offset", "franka-tcp")
    assert code == 2 and not out.exists() and "--shape circle" in capsys.readouterr().err


def test_parse_tool_offset_takes_a_unit_quaternion_and_refuses_others() -> None:
    offset = parse_tool_offset("0.1, 0, 0, 1, 0, 0, 0")
    np.testing.assert_allclose(offset.quat, [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(EnvError, match="not 1"):
        parse_tool_offset("0.1, 0, 0, 2, 0, 0, 0")  # once normalised without a word
    with pytest.raises(EnvError):
        parse_tool_offset("")


def recorded_with_stiffness(end_scale: float = 1.0) -> tuple[object, object]:
    """Stiffness demos as import input in the tcp frame; demo 1's stiffness scaled by ``end_scale`` over its last
    quarter (so that it ends off the common goal stiffness unless end_scale == 1)."""
    from envs.demos.importing import RecordedDemos
    from tests.helpers.stiffness_fixtures import stiffness_demos

    demos = stiffness_demos(n=3, m=40)
    k = demos.stiffness.copy()
    k[1, 30:] *= end_scale
    return demos, RecordedDemos(tuple(demos.pos), tuple(demos.quat), demos.dt, demos.shape, demos.clearance_m,
                                "lerobot", stiffness=tuple(k), tool_frame="tcp")


def import_tcp(recorded: object, snap: bool = False) -> object:
    from envs.demos.importing import ImportConfig, import_demos
    from envs.poses import Pose

    grasp = Pose(*nominal_flange_to_peg_tip("square"))
    return import_demos(recorded, grasp, grasp, recorded.dt, "square", recorded.clearance_m,
                        ImportConfig(num_samples=40, snap_goal=snap))


def test_stiffness_is_carried_through_an_import() -> None:
    demos, recorded = recorded_with_stiffness()
    result = import_tcp(recorded)
    np.testing.assert_allclose(result.demos.stiffness, demos.stiffness, rtol=1e-15)
    np.testing.assert_allclose(result.demos.goal_stiffness, demos.goal_stiffness, rtol=1e-15)


def test_stiffness_off_the_common_goal_fails_unless_snapped(tmp_path: Path) -> None:
    from envs.demos.file import save_demos

    _, recorded = recorded_with_stiffness(end_scale=1.1)
    with pytest.raises(EnvError, match="demo 1: 0.000 mm / 0.000 deg / stiffness 0.065 relative"):
        import_tcp(recorded)
    snapped = import_tcp(recorded, snap=True).demos
    np.testing.assert_array_equal(snapped.stiffness[:, -1], np.broadcast_to(snapped.goal_stiffness, (3, 3, 3)))
    save_demos(tmp_path / "d.npz", snapped)  # validates: symmetric, positive definite, ending at the goal


@pytest.mark.parametrize("option", [("--noise", "realistic"), ("--expert-stiffness", "1500/300/300")])
def test_options_of_the_scripted_expert_are_refused_with_import(tmp_path: Path, capsys, option) -> None:
    """--noise and --expert-stiffness shape the expert's recordings; with --import they would be silently ignored."""
    code, out = run_import(tmp_path, tmp_path / "rec.npz", "--tool-offset", OFFSET_ARG, *option)
    err = capsys.readouterr().err
    assert code == 2 and not out.exists() and err.count("\n") == 1 and option[0] in err and "--import" in err
