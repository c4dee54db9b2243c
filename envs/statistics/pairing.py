"""Whether two evaluations ran the same episodes: their records paired by episode index, refused (one line naming
the first difference) when a start pose or a hole-pose error differs.

Two evaluations with the same --seed and --episodes run every episode from the same start and the same hole-pose
error, so episode i of the base skill and episode i of the candidate form a pair, the unit of the paired statistics
(envs.statistics.fixed_sample, envs.statistics.sequential).
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]

PAIRING_TOLERANCE: float = 1e-9
"""Start poses (m, quaternion components) and perturbations (mm, deg) of a pair agree to this much."""
IMPERFECTION_KEYS: frozenset[str] = frozenset({"hole_friction", "pad_friction", "grasp_lateral_mm", "grasp_tilt_deg",
                                               "grasp_yaw_deg", "payload_mass_error", "joint_friction_scale",
                                               "observed_hole_dx_mm", "observed_hole_dy_mm", "observed_hole_yaw_deg",
                                               "payload_com_x_mm", "payload_com_y_mm",
                                               "actuator_noise_nm", "observed_hole_tilt_deg",
                                               "observed_hole_tilt_dir_deg"})
"""Perturbation keys of the cell's imperfections (envs.task.perturbation), written only where set: what one side of a
paired comparison of an imperfection adds, not what the pairs must share."""


def _numbers(value: Any, length: int) -> FloatArray | None:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return array if array.shape == (length,) else None


def _short(values: FloatArray) -> str:
    return "[" + ", ".join(f"{v:.6g}" for v in values) + "]"


NUMERIC_FIELDS: tuple[str, ...] = ("time_to_insert_s", "insertion_depth_mm", "peak_sustained_wrist_force_n")
"""Episode-record fields the comparison's metrics read as numbers (envs.statistics.comparison.metric_values)."""


def _check_record(record: Any, side: str) -> Mapping[str, Any]:
    if not isinstance(record, Mapping):
        raise EnvError(f"{side}: an episode record must be a JSON object, got {type(record).__name__}")
    for key, length in (("start_pos", 3), ("start_quat", 4)):
        if _numbers(record.get(key), length) is None:
            raise EnvError(f"{side}: episode {record.get('index', '?')} has no numeric {key} of length {length}")
    index = record.get("index")
    if isinstance(index, bool) or not isinstance(index, int) or not isinstance(record.get("success"), bool):
        raise EnvError(f"{side}: an episode record needs an integer 'index' and a boolean 'success'")
    if not isinstance(record.get("perturbation", {}), Mapping):
        raise EnvError(f"{side}: episode {index} has a perturbation that is not an object")
    for key in NUMERIC_FIELDS:  # what the comparison reads: a number or null, never text or a boolean
        value = record.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise EnvError(f"{side}: episode {index} has {key}={value!r}, not a number or null")
    return record


def _by_index(records: Sequence[Any], side: str) -> dict[int, Mapping[str, Any]]:
    out: dict[int, Mapping[str, Any]] = {}
    for record in records:
        r = _check_record(record, side)
        if r["index"] in out:
            raise EnvError(f"{side} holds episode {r['index']} twice")
        out[r["index"]] = r
    return out


def _perturbation_difference(base: Mapping[str, Any], cand: Mapping[str, Any], tolerance: float,
                             treatment: frozenset[str] = frozenset()) -> str | None:
    """What differs between two perturbation dicts (None: equal); an empty one (an episode that never ran:
    worker_died, wall_timeout) carries none and is not compared, and an imperfection only one side has
    (IMPERFECTION_KEYS) is the comparison's treatment, not a difference of the episode."""
    if not base or not cand:
        return None
    for key in sorted(set(base) | set(cand)):
        if key in treatment or ((key not in base or key not in cand) and key in IMPERFECTION_KEYS):
            continue
        if key not in base or key not in cand:
            return f"perturbation {key} is missing in the {'base' if key not in base else 'candidate'}"
        x, y = base[key], cand[key]
        if x is None or y is None:
            if x is not y:
                return f"perturbation {key} differs ({x} vs {y})"
            continue
        if not (isinstance(x, (int, float)) and isinstance(y, (int, float))) or abs(x - y) > tolerance:
            return f"perturbation {key} differs ({x} vs {y})"
    return None


def pair_records(base: Sequence[Any], candidate: Sequence[Any], tolerance: float = PAIRING_TOLERANCE,
                 treatment: frozenset[str] = frozenset()) -> tuple[list[Mapping[str, Any]], list[Mapping[str, Any]]]:
    """Match two evaluations' episode records (``EpisodeRecord.to_dict()``) by episode index; perturbation keys in
    ``treatment`` may differ (what the comparison varies on purpose, e.g. the grasp offset of `pih sensitivity`).

    Returns:
        (base records, candidate records), both sorted by index, record i of each from the same episode.

    Raises:
        EnvError (one line, naming the first differing episode and field): a malformed record, an index twice,
        different episode sets, or a start pose (start_pos, start_quat) or perturbation differing by more
        than ``tolerance``: then the evaluations did not run the same episodes and are not paired.
    """
    b, c = _by_index(base, "base"), _by_index(candidate, "candidate")
    if not b:
        raise EnvError("the base evaluation has no episodes")
    if set(b) != set(c):
        first = min(set(b) ^ set(c))
        raise EnvError(f"the episode sets differ: episode {first} is only in the {'base' if first in b else 'candidate'} "
                       f"({len(b)} vs {len(c)} episodes; run both with the same --episodes and --seed)")
    for index in sorted(b):
        for key, length in (("start_pos", 3), ("start_quat", 4)):
            x, y = _numbers(b[index][key], length), _numbers(c[index][key], length)
            assert x is not None and y is not None  # checked in _check_record
            if np.max(np.abs(x - y)) > tolerance:
                raise EnvError(f"episode {index}: {key} differs ({_short(x)} vs {_short(y)}): the evaluations "
                               "did not start from the same poses (same --seed and start options?)")
        what = _perturbation_difference(b[index].get("perturbation") or {}, c[index].get("perturbation") or {},
                                        tolerance, treatment)
        if what is not None:
            raise EnvError(f"episode {index}: {what}: the evaluations did not use the same hole-pose errors "
                           "(same --seed and task options?)")
    order = sorted(b)
    return [b[i] for i in order], [c[i] for i in order]
