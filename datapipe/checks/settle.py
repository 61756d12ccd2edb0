"""The settle test of a rigid-body drop: when a simulated body counts as at rest. No bpy.

`core/simulation.py` steps Blender's rigid-body world frame by frame and hands each frame's poses
here. A body is at rest at frame k when, over the confirmation window (the last `window` frames,
at least `settle_frames` and at least SETTLE_CONFIRM_S seconds):

- its speed (linear speed of its centre, and angular speed times its radius) stayed below
  min(settle_speed, SETTLE_RELATIVE x its size per second) at every frame, and
- none of its bounding-box corners moved further than min(SETTLE_MOTION, SETTLE_MOTION_RELATIVE x
  its size) from where it was at the window's first frame (k - window).

The window slides with the frames: a body confirmed at rest stays confirmed while every window
passes. (Before, the motion was measured from where the body's rest run began, however long ago:
a pile part creeping at 0.2 mm per window, well inside the test, lost its confirmation after 4 s
of "rest" once the run's total reached 1 mm, and the restarts of a few such parts never lined up,
holding a 120-part drop stage to its frame limit: benchmarks/results/physics.md.)
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

SETTLE_RELATIVE = 0.2          # at rest: speed below this x the part's size per second ...
SETTLE_CONFIRM_S = 0.5         # ... for at least this long, moving less than ...
SETTLE_MOTION = 0.001          # ... this (m) ...
SETTLE_MOTION_RELATIVE = 0.1   # ... or this x its size if that is smaller


def settle_speeds(settle_speed: float, sizes: np.ndarray) -> np.ndarray:
    """The speed (m/s) below which a body of this size counts as at rest."""
    return np.minimum(settle_speed, SETTLE_RELATIVE * np.asarray(sizes, dtype=np.float64))


def confirm_frames(settle_frames: int, dt: float) -> int:
    """The confirmation window in frames of `dt` seconds."""
    return max(int(settle_frames), math.ceil(SETTLE_CONFIRM_S / dt - 1e-9))


class RestTest:
    """The settle test over a sliding window, on n bodies at once (arrays, no per-body loop)."""

    def __init__(self, sizes: np.ndarray, settle_speed: float, settle_frames: int, dt: float,
                 corners: np.ndarray):
        """`sizes`: each body's size (m); `corners`: n x 8 x 3 world corners at frame 0."""
        sizes = np.asarray(sizes, dtype=np.float64)
        self.v_max = settle_speeds(settle_speed, sizes)
        self.motion = np.minimum(SETTLE_MOTION, SETTLE_MOTION_RELATIVE * sizes)
        self.window = confirm_frames(settle_frames, dt)
        self.slow = np.zeros(len(sizes), dtype=int)          # consecutive frames below v_max
        self._corners = deque([np.asarray(corners, dtype=np.float64)], maxlen=self.window + 1)

    def update(self, speed: np.ndarray, corners: np.ndarray) -> np.ndarray:
        """One frame: the bodies' speeds (m/s) and world corners (n x 8 x 3). Returns which bodies
        are at rest (confirmed over the window that ends at this frame)."""
        self.slow = np.where(np.asarray(speed) < self.v_max, self.slow + 1, 0)
        self._corners.append(np.asarray(corners, dtype=np.float64))
        if len(self._corners) <= self.window:
            return np.zeros(len(self.slow), dtype=bool)
        W = np.stack(self._corners)                            # (window + 1) x n x 8 x 3
        moved = np.linalg.norm(W - W[0], axis=3).max(axis=(0, 2))
        return self.creeping() & (moved < self.motion)

    def creeping(self) -> np.ndarray:
        """Which bodies were below their at-rest speed at every frame of the window, whether or
        not they moved further than the motion limit (at rest, or creeping: sliding slowly on the
        pile). A drop stage that is not the last may end when every body is at least creeping
        (core/simulation.drop_in_stages): the creeping parts stay ACTIVE into the next stage."""
        return self.slow >= self.window
