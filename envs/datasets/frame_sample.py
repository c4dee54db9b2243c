"""Evenly spaced, downsampled camera frames of a stream whose length is not known in advance: what a video
feature's statistics (LeRobot's meta/stats.json) are computed from while the frames are rendered, so the
encoded MP4 never has to be decoded again.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError

#: A frame whose long side has at least this many pixels is downsampled (LeRobot's max_size_threshold).
DOWNSAMPLE_FROM_PX: int = 300
#: ... by taking every k-th pixel, k = long side // this (LeRobot's target_size).
DOWNSAMPLE_TO_PX: int = 150


def downsample(frame: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """(H, W, 3) -> every k-th row and column, k = max(H, W) // 150 when max(H, W) >= 300, else the frame.

    The reduction LeRobot applies to the images its statistics are computed from
    (lerobot/datasets/compute_stats.py, ``auto_downsample_height_width``).
    """
    long_side = max(frame.shape[0], frame.shape[1])
    if long_side < DOWNSAMPLE_FROM_PX:
        return frame
    k = long_side // DOWNSAMPLE_TO_PX
    return frame[::k, ::k]


class FrameSample:
    """Keeps evenly spaced frames of a stream: every ``stride``-th frame, downsampled.

    When more than 2 n frames are kept, every other one is dropped and the stride doubles, so the kept frames
    are always those at indices 0, s, 2s, ... (s a power of two) and number between n and 2 n once the stream
    has more than 2 n frames (all of them before): an even spread over the whole stream without knowing its
    length, in O(n) memory.
    """

    def __init__(self, frames: int = 100):
        if frames < 1:
            raise EnvError(f"frame sample of {frames} frames: must be >= 1")
        self.target = frames
        self.stride = 1
        self.seen = 0
        self.kept: list[npt.NDArray[np.uint8]] = []

    def add(self, frame: npt.NDArray[np.uint8]) -> None:
        """Offer the next frame of the stream (H, W, 3) uint8."""
        if self.seen % self.stride == 0:
            self.kept.append(np.array(downsample(frame), dtype=np.uint8))
            if len(self.kept) > 2 * self.target:
                self.kept = self.kept[::2]
                self.stride *= 2
        self.seen += 1

    def pixels(self) -> npt.NDArray[np.float64]:
        """Every kept pixel as an (N, 3) array scaled to [0, 1].

        Raises:
            EnvError: no frame was offered.
        """
        if not self.kept:
            raise EnvError("frame sample: no frame was offered")
        return np.stack(self.kept).reshape(-1, 3).astype(np.float64) / 255.0
