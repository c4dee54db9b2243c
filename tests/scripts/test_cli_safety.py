"""Every `pih` command refuses bad input and unsafe outputs before any work, with one line and exit 2, touching
nothing; an operating-system error while writing (a full disk, a read-only folder) is one line and exit 1
and leaves no half-written output (envs/io/owned_output.py on pihutil/atomic.py, scripts/options.py).

Each case: the command line (``{tmp}`` is the case's folder, which holds a checkpoint ``model/``, a demo
file ``demos.npz`` and whatever the case prepares), the files to prepare, the exit status and a fragment of
the one-line message; every file in the folder must be byte for byte as before.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from pihutil import atomic
from rflow.skill_io import save_skill
from scripts.cli import main
from tests.helpers.skill_fixtures import synthetic_demos, tiny_skill, write_demo_file


def _foreign(name: str) -> Callable[[Path], None]:
    """Prepare a file (or, for a name ending in /, a folder with a file) that pih did not write."""
    def prepare(tmp: Path) -> None:
        path = tmp / name.rstrip("/")
        path.parent.mkdir(parents=True, exist_ok=True)
        if name.endswith("/"):
            path.mkdir()
            (path / "notes.txt").write_text("keep me")
        else:
            path.write_bytes(b'{"mine": "keep me"}' if path.suffix == ".json" else b"keep me")
    return prepare


def _recording(tmp: Path) -> None:
    """A recording for `pih demos --import` (tool frame = flange)."""
    demos = synthetic_demos(n=1)
    np.savez(tmp / "rec.npz", pos=demos.pos, quat=demos.quat, dt=np.float64(demos.dt))


def _config(layers: object) -> Callable[[Path], None]:
    def prepare(tmp: Path) -> None:
        (tmp / "best.json").write_text(json.dumps({"format": "pih-rflow-train-config", "version": 1,
                                                   "train_config": {"model": {"layers": layers}}}))
    return prepare


def _pickled_demos(tmp: Path) -> None:
    """A demo file whose arrays need unpickling (object arrays)."""
    demos = synthetic_demos()
    np.savez(tmp / "pickled.npz", pos=np.array([object()] * 3, dtype=object), quat=demos.quat, dt=demos.dt,
             goal_pos=demos.goal_pos, goal_quat=demos.goal_quat, shape="square", clearance_m=0.001,
             config_json="{}")


def _pickled_preview(tmp: Path) -> None:
    """The checkpoint's demo preview (read by --figure after the episodes) holds an object array."""
    np.savez(tmp / "model" / "demos.npz", pos=np.array([object()], dtype=object), quat=np.zeros((1, 2, 4)), dt=0.1)


def _npy_named_npz(tmp: Path) -> None:
    """A .npy file (one bare array) under a .npz name."""
    with open(tmp / "array.npz", "wb") as handle:
        np.save(handle, np.zeros((3, 4)))


def _metadata(key: str, value: object) -> Callable[[Path], None]:
    """The checkpoint's skill.json metadata with ``key`` set to ``value``."""
    def prepare(tmp: Path) -> None:
        path = tmp / "model" / "skill.json"
        record = json.loads(path.read_text())
        record["metadata"][key] = value
        path.write_text(json.dumps(record))
    return prepare


def _model_json(key: str, value: object) -> Callable[[Path], None]:
    """The position model's model.json with ``key`` set to ``value``."""
    def prepare(tmp: Path) -> None:
        path = tmp / "model" / "position" / "model.json"
        record = json.loads(path.read_text())
        record[key] = value
        path.write_text(json.dumps(record))
    return prepare


def _model_field(key: str, value: object) -> Callable[[Path], None]:
    """The position model's model.json with its architecture's ``key`` (record["model"]) set to ``value``."""
    def prepare(tmp: Path) -> None:
        path = tmp / "model" / "position" / "model.json"
        record = json.loads(path.read_text())
        record["model"][key] = value
        path.write_text(json.dumps(record))
    return prepare


def _pickled_weights(tmp: Path) -> None:
    """weights.pt as a pickle of a plain dict (pickle protocol 4): refused without unpickling."""
    import pickle

    (tmp / "model" / "position" / "weights.pt").write_bytes(pickle.dumps({"w": [1.0]}, protocol=4))


def _scene_config(scene: object) -> Callable[[Path], None]:
    """A demo file whose recorded config holds ``scene``."""
    def prepare(tmp: Path) -> None:
        demos = synthetic_demos()
        np.savez(tmp / "scene.npz", pos=demos.pos, quat=demos.quat, dt=demos.dt, goal_pos=demos.goal_pos,
                 goal_quat=demos.goal_quat, shape="square", clearance_m=0.001,
                 config_json=json.dumps({"scene": scene}))
    return prepare


def _nan_goal(tmp: Path) -> None:
    demos = synthetic_demos()
    np.savez(tmp / "nan.npz", pos=demos.pos, quat=demos.quat, dt=demos.dt, goal_pos=np.array([np.nan, 0.0, 0.0]),
             goal_quat=demos.goal_quat, shape="square", clearance_m=0.001, config_json="{}")


def _task_file(time_limit: str) -> Callable[[Path], None]:
    """A task file with the given time limit."""
    def prepare(tmp: Path) -> None:
        (tmp / "t.toml").write_text(f"version = 1\ntime_limit_s = {time_limit}\n")
    return prepare


@dataclass(frozen=True)
class Case:
    argv: str
    message: str
    prepare: tuple[Callable[[Path], None], ...] = field(default=())
    code: int = 2


FAST_EVAL = "--episodes 1 --time-limit-s 0.05 --quiet"
OVERWRITE = ["", " --overwrite"]

CASES: dict[str, Case] = {
    # a file pih did not write is never replaced, with or without --overwrite
    **{f"demos-foreign{o}": Case(f"demos --num 1 --out {{tmp}}/d.npz{o}", "not written by pih", (_foreign("d.npz"),))
       for o in OVERWRITE},
    **{f"import-foreign{o}": Case(f"demos --import {{tmp}}/rec.npz --tool-offset flange --out {{tmp}}/d.npz{o}",
                                  "not written by pih", (_recording, _foreign("d.npz"))) for o in OVERWRITE},
    **{f"evaluate-{kind}-foreign{o}": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --{kind} {{tmp}}/x.{ext}{o}",
                                           "not written by pih", (_foreign(f"x.{ext}"),))
       for kind, ext in (("json", "json"), ("video", "mp4"), ("figure", "png")) for o in OVERWRITE},
    **{f"train-foreign-{what}{o}": Case(f"train --demos {{tmp}}/demos.npz --out {{tmp}}/ck --epochs 1{o}",
                                        "not a checkpoint", (_foreign("ck/" if what == "folder" else "ck"),))
       for what in ("file", "folder") for o in OVERWRITE},
    "sweep-foreign": Case("sweep --model {tmp}/model --clearance-mm 0.2 --out {tmp}/sw", "--overwrite",
                          (_foreign("sw/sweep.json"),)),
    "sweep-foreign --overwrite": Case("sweep --model {tmp}/model --clearance-mm 0.2 --out {tmp}/sw --overwrite",
                                      "not written by pih", (_foreign("sw/sweep.json"),)),
    **{f"render-foreign{o}": Case(f"render --demos {{tmp}}/demos.npz --out {{tmp}}/v.mp4{o}", "not written by pih",
                                  (_foreign("v.mp4"),)) for o in OVERWRITE},
    **{f"lasa-foreign{o}": Case(f"lasa --shape NShape --json {{tmp}}/r.json{o}", "not written by pih",
                                (_foreign("r.json"),)) for o in OVERWRITE},
    "lasa-all-foreign --overwrite": Case("lasa --all --shapes NShape --out {tmp}/l --overwrite", "not written by pih",
                                         (_foreign("l/results.json"),)),
    **{f"bench-foreign{o}": Case(f"bench --only ik --json {{tmp}}/b.json{o}", "not written by pih",
                                 (_foreign("b.json"),)) for o in OVERWRITE},
    **{f"run-foreign{o}": Case(f"run --root {{tmp}} --name r{o}", "not written by pih", (_foreign("r/eval.json"),))
       for o in OVERWRITE},
    **{f"search-foreign{o}": Case(f"search --out {{tmp}}/s --trials 1{o}", "not written by pih",
                                  (_foreign("s/best.json"),)) for o in OVERWRITE},
    **{f"export-foreign{o}": Case(f"export --demos {{tmp}}/demos.npz --format lerobot --out {{tmp}}/ds{o}",
                                  "not a `pih export` output", (_foreign("ds/"),)) for o in OVERWRITE},
    "benchmark-foreign": Case("benchmark --demo-seeds 0 --episodes 1 --out {tmp}/b", "not a `pih benchmark` folder",
                              (_foreign("b/"),)),
    # an output is never an input, nor inside an input checkpoint
    "evaluate-json-is-the-checkpoint's": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} "
                                              "--json {tmp}/model/skill.json --overwrite", "inside the input"),
    "evaluate-json-into-the-checkpoint": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --json {{tmp}}/model/e.json",
                                              "inside the input"),
    "import-out-is-the-input": Case("demos --import {tmp}/rec.npz --tool-offset flange --out {tmp}/rec.npz --overwrite",
                                    "input", (_recording,)),
    "export-out-into-the-checkpoint": Case("export --episodes {tmp}/e.json --model {tmp}/model --format lerobot "
                                           "--out {tmp}/model/ds", "inside the input"),
    "train-out-holds-the-demos": Case("train --demos {tmp}/model/x.npz --out {tmp}/model --overwrite",
                                      "holds the input", (lambda tmp: shutil.copy(tmp / "demos.npz", tmp / "model" / "x.npz"),)),
    # seeds and counts, checked while parsing
    **{f"{command}-seed-negative": Case(f"{command} --seed -1 {rest}", "argument --seed")
       for command, rest in (("demos", "--out {tmp}/d.npz"), ("evaluate", "--model {tmp}/model"),
                             ("train", "--demos {tmp}/demos.npz --out {tmp}/ck"),
                             ("sweep", "--model {tmp}/model --clearance-mm 0.2 --out {tmp}/sw"))},
    "evaluate-seed-2**32": Case("evaluate --model {tmp}/model --seed 4294967296", "argument --seed"),
    "evaluate-episodes-1e12": Case("evaluate --model {tmp}/model --episodes 1e12", "argument --episodes"),
    "evaluate-episodes-huge": Case("evaluate --model {tmp}/model --episodes 1000000000000", "100,000"),
    "sweep-episodes-huge": Case("sweep --model {tmp}/model --clearance-mm 0.2 --out {tmp}/sw --episodes 200000",
                                "argument --episodes"),
    "demos-num-huge": Case("demos --num 5000 --out {tmp}/d.npz", "argument --num"),
    "run-episodes-huge": Case("run --root {tmp} --episodes 1000000", "argument --episodes"),
    "evaluate-old-unit-spelling": Case("evaluate --model {tmp}/model --pos-range 0.05", "unrecognized arguments"),
    # config files and demo files by content
    "train-config-float-layers": Case("train --demos {tmp}/demos.npz --out {tmp}/ck --config {tmp}/best.json",
                                      "model.layers = 2.5 must be an integer", (_config(2.5),)),
    "lasa-config-bool-layers": Case("lasa --shape NShape --config {tmp}/best.json", "model.layers = true",
                                    (_config(True),)),
    "train-npy-named-npz": Case("train --demos {tmp}/array.npz --out {tmp}/ck", "not a .npz archive",
                                (_npy_named_npz,)),
    "import-npy-named-npz": Case("demos --import {tmp}/array.npz --tool-offset flange --out {tmp}/i.npz",
                                 "not a .npz archive", (_npy_named_npz,)),
    "evaluate-metadata-clearance-text": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}", "clearance_m='x' must be",
                                             (_metadata("clearance_m", "x"),)),
    "evaluate-metadata-scene-number": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}", "'scene' must be a JSON",
                                           (_metadata("scene", 5),)),
    "evaluate-metadata-demo-starts-pos-text": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}",
                                                   "skill.json: metadata 'demo_starts.pos' must be finite numbers",
                                                   (_metadata("demo_starts", {"pos": "abc", "quat": [[1, 0, 0, 0]]}),)),
    "evaluate-metadata-demo-starts-text": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}",
                                               "skill.json: metadata 'demo_starts' must be an object",
                                               (_metadata("demo_starts", "some text"),)),
    "evaluate-model-width-text": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}",
                                      "position/model.json: model.width='16' must be an integer",
                                      (_model_field("width", "16"),)),
    "evaluate-model-layers-float": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}",
                                        "position/model.json: model.layers=2.5 must be an integer",
                                        (_model_field("layers", 2.5),)),
    "evaluate-model-dim-text": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}", "model.json: dim='3' must be an integer",
                                    (_model_json("dim", "3"),)),
    "evaluate-model-dim-huge": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}", "dim=1000000000000 differs",
                                    (_model_json("dim", 10**12),)),
    "evaluate-pickled-weights": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL}", "which pih never does",
                                     (_pickled_weights,)),
    "evaluate-journal-suffix": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --journal {{tmp}}/j.txt",
                                    "must end in .jsonl"),
    "render-width-not-multiple-of-8": Case("render --demos {tmp}/demos.npz --width-px 17 --out {tmp}/r.mp4",
                                           "--width-px 17"),
    "render-scene-list": Case("render --demos {tmp}/scene.npz --out {tmp}/r.mp4", "'scene' must be a JSON object",
                              (_scene_config([1, 2]),)),
    "train-scene-chamfer-list": Case("train --demos {tmp}/scene.npz --out {tmp}/ck", "chamfer_m=[1] must be a number",
                                     (_scene_config({"chamfer_m": [1]}),)),
    # options this use of the command would ignore
    "lasa-all-with-shape": Case("lasa --all --out {tmp}/la --shape Angle", "--shape: applies to a single --shape"),
    "lasa-shape-with-shapes": Case("lasa --shape Angle --shapes Nope", "--shapes: applies to --all only"),
    "demos-tool-offset-without-import": Case("demos --num 1 --out {tmp}/d.npz --tool-offset 1,2",
                                             "--tool-offset: applies to --import only"),
    "demos-check-with-out": Case("demos --check 1 --out {tmp}/d.npz", "--out: not with --check"),
    "evaluate-camera-without-video": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --camera side",
                                         "--camera: applies to --video only"),
    "evaluate-video-episodes-alone": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --video-episodes 0",
                                          "--video-episodes: applies to --video"),
    "compare-paired-with-chunk": Case("compare {tmp}/a.json {tmp}/b.json --chunk 3",
                                      "--chunk: applies to --sequential only"),
    "evaluate-hole-error-mm-huge": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --hole-error-mm 1e6",
                                        "--hole-error-mm 1e+06: out of range"),
    "sweep-clearance-mm-huge": Case("sweep --model {tmp}/model --clearance-mm 0.2,100 --out {tmp}/sw",
                                    "--clearance-mm 100: out of range"),
    "evaluate-speed-huge": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --speed 1e300", "argument --speed"),
    "evaluate-pos-range-huge": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --pos-range-mm 1e9",
                                    "--pos-range-mm 1e+09: out of range"),
    "benchmark-demos-zero": Case("benchmark --demos 0 --out {tmp}/b", "argument --demos"),
    "benchmark-start-seed-offset-huge": Case("benchmark --start-seed-offset 99999999999 --out {tmp}/b",
                                             "argument --start-seed-offset"),
    "compare-max-episodes-negative": Case("compare --sequential --max-episodes -5", "argument --max-episodes"),
    "train-demos-folder": Case("train --demos {tmp}/model --out {tmp}/ck", "is a folder, not a .npz file"),
    "train-overwrite-checkpoint-with-notes": Case("train --demos {tmp}/demos.npz --out {tmp}/model --overwrite",
                                                  "holds files its checkpoint did not write",
                                                  (_foreign("model/n.txt"),)),
    "import-with-num": Case("demos --import {tmp}/rec.npz --tool-offset flange --num 3 --out {tmp}/i.npz",
                            "--num: records the scripted expert's demos", (_recording,)),
    "export-camera-without-video": Case("export --demos {tmp}/demos.npz --format lerobot --camera side --out {tmp}/ex",
                                        "--camera: applies to --video only"),
    "evaluate-policy-adaptation-off": Case("evaluate --policy tests.helpers.policies_for_tests:hold "
                                           "--demos {tmp}/demos.npz --adaptation-off push",
                                           "--adaptation-off: not with --policy"),
    "run-subsample-too-large": Case("run --root {tmp} --name r --subsample 5000", "--subsample 5000"),
    "train-pickled-demos": Case("train --demos {tmp}/pickled.npz --out {tmp}/ck", "not a readable .npz",
                                (_pickled_demos,)),
    "evaluate-pickled-preview": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --figure {{tmp}}/f.png",
                                     "not a readable demo preview", (_pickled_preview,)),
    "train-nan-goal": Case("train --demos {tmp}/nan.npz --out {tmp}/ck", "'goal_pos' contains NaN", (_nan_goal,)),
    # numbers past what the code below takes (pihutil.bounds): refused before any work, not failed in every episode
    "evaluate-unit-timeout-1e10": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --unit-timeout-s 1e10",
                                       "argument --unit-timeout-s"),
    "sweep-unit-timeout-1e10": Case("sweep --model {tmp}/model --clearance-mm 0.2 --out {tmp}/sw --unit-timeout-s 1e10",
                                    "argument --unit-timeout-s"),
    "evaluate-stiffness-1e300": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --stiffness constant:1e300",
                                     "K must be in [0.001, 1e+06] N/m"),
    "evaluate-lookahead-1e300": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --lookahead-s 1e300",
                                     "argument --lookahead-s"),
    "evaluate-feedforward-1e300": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --feedforward 1e300",
                                       "argument --feedforward"),
    "benchmark-workers-1e20": Case("benchmark --workers 100000000000000000000 --out {tmp}/b", "argument --workers"),
    "benchmark-demo-seeds-huge": Case("benchmark --demo-seeds 0-99999999999 --out {tmp}/b",
                                      "every seed must be in 0..4,294,967,295"),
    "benchmark-demo-seeds-many": Case("benchmark --demo-seeds 0-999999 --out {tmp}/b", "1,000,000 replicates, at most"),
    "benchmark-episodes-huge": Case("benchmark --episodes 1000000 --out {tmp}/b", "argument --episodes"),
    "evaluate-task-file-time-limit-1e12": Case(f"evaluate --model {{tmp}}/model {FAST_EVAL} --task {{tmp}}/t.toml",
                                               "time_limit_s=1000000000000.0 must be", (_task_file("1e12"),)),
    "import-tool-offset-1e300": Case("demos --import {tmp}/rec.npz --tool-offset 1e300,0,0,1,0,0,0 --out {tmp}/d.npz",
                                     "the offset's length", (_recording,)),
    "train-memory": Case("train --demos {tmp}/demos.npz --out {tmp}/ck --width 4096 --layers 64 --batch-size 1000000",
                         "of memory, more than the"),
    "lasa-memory": Case("lasa --shape NShape --layers 64 --batch-size 1000000", "of memory, more than the"),
    "train-lr-1e300": Case("train --demos {tmp}/demos.npz --out {tmp}/ck --lr 1e300", "argument --lr"),
    "import-non-unit-tool-quaternion": Case("demos --import {tmp}/rec.npz --tool-offset 0,0,0.1,0.7071,0,0,0.7071 "
                                            "--out {tmp}/d.npz", "not 1", (_recording,)),
}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_skill(tmp_path_factory.mktemp("ck") / "model", tiny_skill())


@pytest.fixture
def folder(tmp_path: Path, checkpoint: Path) -> Path:
    """The case's folder: a copy of the checkpoint and a demo file."""
    shutil.copytree(checkpoint, tmp_path / "model")
    write_demo_file(tmp_path)
    return tmp_path


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``folder``."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


def one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("name", list(CASES))
def test_refused_before_any_work_with_one_line_touching_nothing(name: str, folder: Path, capsys,
                                                                monkeypatch) -> None:
    case = CASES[name]
    if name.startswith("search") and not _importable("optuna"):
        pytest.skip("the search extra is not installed")
    for prepare in case.prepare:
        prepare(folder)
    before = snapshot(folder)
    monkeypatch.chdir(folder)  # `pih bench` looks for runs/default/model here
    assert main(case.argv.format(tmp=folder).split()) == case.code
    err = one_line_error(capsys)
    assert err.startswith(f"pih {case.argv.split()[0]}: error:") and case.message in err, err
    assert snapshot(folder) == before


def _importable(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


# ---- the output folder: not writable, too full --------------------------------------------------------------
def test_a_read_only_output_folder_is_refused_before_work(folder: Path, capsys, monkeypatch) -> None:
    _recording(folder)
    (folder / "ro").mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: False if Path(path) == folder / "ro" else real(path, mode))
    before = snapshot(folder)
    assert main(["demos", "--import", str(folder / "rec.npz"), "--tool-offset", "flange",
                 "--out", str(folder / "ro" / "d.npz")]) == 2
    assert "is not writable" in one_line_error(capsys) and snapshot(folder) == before


def test_a_full_file_system_is_refused_before_work(folder: Path, capsys, monkeypatch) -> None:
    monkeypatch.setattr(shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(10 << 30, 10 << 30, 1000))
    before = snapshot(folder)
    assert main(["evaluate", "--model", str(folder / "model"), *FAST_EVAL.split(), "--json", str(folder / "e.json")]) == 2
    assert "MiB free" in one_line_error(capsys) and snapshot(folder) == before


# ---- operating-system errors while writing: exit 1, one line, nothing half-written --------------------------
def _fail_temporary(monkeypatch, folder: Path, target: str, how: str) -> None:
    """Make the temporary output file ending in ``target`` in ``folder`` fail: "enospc" points it at /dev/full (a real
    full device: every write fails with ENOSPC), "eacces" refuses to create it."""
    real = tempfile.mkstemp

    def mkstemp(suffix: str = "", prefix: str = "", dir: str | None = None) -> tuple[int, str]:  # noqa: A002
        if dir is None or Path(dir) != folder or not suffix.endswith(target):
            return real(suffix=suffix, prefix=prefix, dir=dir)
        if how == "eacces":
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), dir)
        fd, name = real(suffix=suffix, prefix=prefix, dir=dir)
        os.close(fd)
        os.unlink(name)
        os.symlink("/dev/full", name)
        return os.open(folder / ".scratch-for-fchmod", os.O_CREAT | os.O_WRONLY), name

    monkeypatch.setattr(atomic.tempfile, "mkstemp", mkstemp)  # the one atomic write (pihutil.atomic)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name)


def test_a_full_disk_while_writing_json_is_exit_1_and_no_file(folder: Path, capsys, monkeypatch) -> None:
    _fail_temporary(monkeypatch, folder, ".json", "enospc")
    out = folder / "e.json"
    assert main(["evaluate", "--model", str(folder / "model"), *FAST_EVAL.split(), "--json", str(out)]) == 1
    err = one_line_error(capsys)
    assert f"{out}: No space left on device" in err
    assert not out.exists() and _leftovers(folder) == []


def test_a_full_disk_while_encoding_mp4_is_exit_1_and_no_file(folder: Path, capsys, monkeypatch) -> None:
    _fail_temporary(monkeypatch, folder, ".mp4", "enospc")
    out = folder / "v.mp4"
    assert main(["evaluate", "--model", str(folder / "model"), *FAST_EVAL.split(), "--video", str(out),
                 "--video-episodes", "0"]) == 1
    err = one_line_error(capsys)
    assert f"{out}: ffmpeg could not write the video" in err
    assert not out.exists() and _leftovers(folder) == []


def test_permission_denied_while_writing_is_exit_1_and_no_file(folder: Path, capsys, monkeypatch) -> None:
    _recording(folder)
    _fail_temporary(monkeypatch, folder, ".npz", "eacces")
    out = folder / "d.npz"
    assert main(["demos", "--import", str(folder / "rec.npz"), "--tool-offset", "flange", "--out", str(out)]) == 1
    assert f"{out}: Permission denied" in one_line_error(capsys) and not out.exists()
