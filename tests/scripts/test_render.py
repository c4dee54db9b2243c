"""`pih render`: a demo, or an evaluation's episode replayed (as `pih export` replays it), to MP4 with the overlay;
what it cannot render said in one line; and `pih bench` reporting the video's cost as a ratio to the physics."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v2 as imageio
import pytest

from rflow.skill_io import save_skill
from scripts.cli import main
from tests.helpers.skill_fixtures import tiny_skill

RUN = ["--episodes", "2", "--time-limit-s", "0.3", "--pos-range-mm", "10", "--quiet"]


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("eval")
    model = save_skill(folder / "model", tiny_skill())
    assert main(["evaluate", "--model", str(model), *RUN, "--json", str(folder / "e.json")]) == 0
    return folder / "e.json"


@pytest.mark.slow
def test_an_evaluations_episode_renders_from_its_replay(evaluation: Path, tmp_path: Path, capsys) -> None:
    record = json.loads(evaluation.read_text())["per_episode"][1]
    out = tmp_path / "episode.mp4"
    assert main(["render", "--episodes", str(evaluation), "--index", "1", "--out", str(out), "--camera", "cutaway",
                 "--width-px", "160", "--height-px", "120"]) == 0
    assert f"episode 1 of {evaluation}" in capsys.readouterr().out
    reader = imageio.get_reader(out)
    assert reader.count_frames() == int(record["steps"] * 0.01 * 30 + 1e-9) + 1  # 30 fps of its simulated time
    reader.close()


@pytest.mark.parametrize("extra, words", [(["--index", "7"], "has no episode 7"),
                                          (["--hold-s", "2"], "--hold-s: applies to --demos only")])
def test_what_render_cannot_do_is_one_line(evaluation: Path, tmp_path: Path, capsys, extra, words) -> None:
    assert main(["render", "--episodes", str(evaluation), *extra, "--out", str(tmp_path / "v.mp4")]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and not (tmp_path / "v.mp4").exists()


def test_an_evaluation_of_a_policy_says_it_cannot_be_replayed(tmp_path: Path, capsys) -> None:
    source = tmp_path / "mine.json"
    source.write_text(json.dumps({"policy": {"spec": "mymodule:make"}, "per_episode": [{"index": 0}]}))
    assert main(["render", "--episodes", str(source), "--out", str(tmp_path / "v.mp4")]) == 2
    assert "cannot be replayed" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_reports_the_videos_cost_as_a_ratio_to_the_episodes_physics(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "render", "--json", str(out)]) == 0
    render = json.loads(out.read_text())["render"]
    assert render["video_over_physics"] == pytest.approx(render["video_s"] / render["physics_s"])
    assert render["video_over_physics"] > 0.0
