import json
from dataclasses import dataclass

import numpy as np

from envs.io.jsonable import to_jsonable


@dataclass(frozen=True)
class _Record:
    pos: np.ndarray
    shape: str
    depth_m: np.float64
    tags: tuple


def test_nested_record_round_trips_through_json():
    record = {"a": _Record(np.array([1.0, 2.0]), "square", np.float64(0.03), (np.int64(1), 2)), 3: [np.zeros(2)]}
    expected = {"a": {"pos": [1.0, 2.0], "shape": "square", "depth_m": 0.03, "tags": [1, 2]}, "3": [[0.0, 0.0]]}
    assert json.loads(json.dumps(to_jsonable(record))) == expected
