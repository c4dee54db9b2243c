"""The frames a video's statistics come from: evenly spaced over a stream of unknown length, bounded in number,
downsampled as LeRobot's statistics are."""

from __future__ import annotations

import numpy as np
import pytest

from envs.datasets.frame_sample import FrameSample, downsample
from envs.errors import EnvError


def numbered(i: int, size: int = 8) -> np.ndarray:
    """A frame whose every pixel holds i (mod 256) in its first channel and i // 256 in its second."""
    frame = np.zeros((size, size, 3), np.uint8)
    frame[..., 0], frame[..., 1] = i % 256, i // 256
    return frame


def kept_indices(sample: FrameSample) -> list[int]:
    return [int(f[0, 0, 0]) + 256 * int(f[0, 0, 1]) for f in sample.kept]


@pytest.mark.parametrize("length", [1, 7, 200, 201, 1000, 4097])
def test_kept_frames_are_evenly_spaced_from_the_first_and_bounded(length: int) -> None:
    sample = FrameSample(frames=100)
    for i in range(length):
        sample.add(numbered(i))
    kept = kept_indices(sample)
    assert kept[0] == 0 and len(set(np.diff(kept))) <= 1  # one stride
    assert len(kept) == length if length <= 200 else 100 <= len(kept) <= 200
    assert kept[-1] > length - 1 - sample.stride  # covers the stream up to its last stride


def test_large_frames_are_downsampled_as_lerobot_does() -> None:
    assert downsample(np.zeros((480, 640, 3), np.uint8)).shape == (120, 160, 3)  # k = 640 // 150 = 4
    assert downsample(np.zeros((128, 128, 3), np.uint8)).shape == (128, 128, 3)  # under 300 px: unchanged


def test_pixels_are_scaled_to_unit_range_and_an_empty_sample_is_refused() -> None:
    sample = FrameSample()
    with pytest.raises(EnvError, match="no frame"):
        sample.pixels()
    sample.add(np.full((4, 4, 3), 255, np.uint8))
    assert sample.pixels().shape == (16, 3) and np.all(sample.pixels() == 1.0)
