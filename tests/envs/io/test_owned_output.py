"""envs.io.owned_output: a failed write leaves the earlier file and no temporary one; pih's own outputs are recognised
by their marker (and a registered file no longer once changed); JSON is strict; a cut MP4 is not whole."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from envs.io.owned_output import is_own_output, save_npz, write_file, write_json, write_text
from envs.media.video import Mp4Writer, check_mp4


def test_a_write_failing_half_way_leaves_the_earlier_file_and_no_temporary(tmp_path: Path) -> None:
    path = write_json(tmp_path / "r.json", {"a": 1})

    def fail(handle) -> None:
        handle.write('{"a": ')
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="r.json"):
        write_file(path, fail)
    assert json.loads(path.read_text())["a"] == 1 and [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_non_finite_numbers_are_written_as_null(tmp_path: Path) -> None:
    record = json.loads(write_json(tmp_path / "r.json", {"goal": [math.nan, math.inf, 1.0]}).read_text())
    assert record["goal"] == [None, None, 1.0] and record["pih"]["command"]


@pytest.mark.parametrize("write, name", [(lambda p: write_json(p, {"a": 1}), "x.json"),
                                         (lambda p: save_npz(p, {"a": np.zeros(2)}), "x.npz"),
                                         (lambda p: write_text(p, "table"), "x.md")])
def test_own_outputs_are_recognised_and_foreign_ones_are_not(tmp_path: Path, write, name: str) -> None:
    path = tmp_path / name
    write(path)
    assert is_own_output(path)
    path.write_bytes(b'{"a": 1}')  # the same name, someone else's bytes
    assert not is_own_output(path)


def test_a_cut_mp4_is_not_whole(tmp_path: Path) -> None:
    writer = Mp4Writer(tmp_path / "v.mp4", fps=30)
    for k in range(5):
        writer.append(np.full((64, 64, 3), 40 * k, dtype=np.uint8))
    path = writer.close()
    assert check_mp4(path) is None and is_own_output(path)
    data = path.read_bytes()
    (tmp_path / "cut.mp4").write_bytes(data[: len(data) // 2])
    assert "past the end" in check_mp4(tmp_path / "cut.mp4")
