"""The settle test (datapipe/checks/settle.py) on made-up trajectories: no Blender.

Ground truth is the test's own definition, applied by hand to trajectories whose speeds and
displacements are known exactly: a body moving at constant velocity v moves v x t."""
import numpy as np

from datapipe.checks.settle import RestTest, confirm_frames

DT = 1 / 24                     # Blender's default 24 frames per second
SIZE = 0.04                     # m: a 40 mm part, so the limits are the absolute ones below
SETTLE_SPEED = 0.005            # m/s (bin_picking.json's simulation.settle_speed)
BOX = np.array([[x, y, z] for x in (0, SIZE) for y in (0, 0.01) for z in (0, 0.01)], dtype=np.float64)


def _feed(velocities: np.ndarray, flag) -> np.ndarray:
    """Feed per-frame velocities (frames x n x 3, m/s) of n translating boxes to one RestTest;
    returns frames x n of `flag(test, update's at-rest flags)` after each frame."""
    frames, n, _ = velocities.shape
    pos = np.zeros((n, 3))
    test = RestTest(np.full(n, SIZE), SETTLE_SPEED, 5, DT, BOX[None] + pos[:, None])
    out = []
    for k in range(frames):
        pos = pos + velocities[k] * DT
        out.append(flag(test, test.update(np.linalg.norm(velocities[k], axis=1), BOX[None] + pos[:, None])))
    return np.array(out)


def run(velocities: np.ndarray) -> np.ndarray:
    """Frames x n at-rest flags of n translating boxes fed these velocities."""
    return _feed(velocities, lambda test, rest: rest)


def test_window_is_half_a_second_at_24_fps():
    assert confirm_frames(5, DT) == 12 and confirm_frames(20, DT) == 20


def test_steady_creep_inside_the_limits_stays_at_rest():
    """0.4 mm/s: 0.2 mm per 12-frame window, far inside the 1 mm and 5 mm/s limits. Confirmed at
    the end of the first window and never withdrawn: measuring the motion from where the rest run
    began (the test before) withdrew it after 1 mm in total, 2.5 s later, and a pile of such
    parts whose restarts never lined up held a drop stage to its frame limit."""
    v = np.zeros((300, 1, 3))
    v[:, 0, 0] = 0.0004
    rest = run(v)[:, 0]
    assert not rest[:11].any() and rest[11:].all()


def test_a_faster_creep_is_not_at_rest():
    """2.5 mm/s: under the 5 mm/s speed limit at every frame, but 1.25 mm per window: over 1 mm."""
    v = np.zeros((100, 1, 3))
    v[:, 0, 0] = 0.0025
    assert not run(v)[:, 0].any()


def test_one_fast_frame_restarts_the_confirmation():
    """A frame above the speed limit (a knock) withdraws the rest; a full window confirms it again."""
    v = np.zeros((60, 2, 3))
    v[30, 0, 2] = 0.006                # body 0: 6 mm/s for one frame (0.25 mm: the motion test passes)
    rest = run(v)
    assert rest[11:30, 0].all() and not rest[30:42, 0].any() and rest[42:, 0].all()
    assert rest[11:, 1].all()          # body 1 never moved


def test_back_and_forth_inside_the_window_counts_its_furthest_point():
    """A body that goes 1.2 mm out and comes back within one window (each frame under 5 mm/s) is
    not at rest while a window holds two points of its path more than 1 mm apart, though it ends
    where it began."""
    v = np.zeros((60, 1, 3))
    v[20:26, 0, 0] = 0.0048            # 6 frames x 0.2 mm = 1.2 mm out, under 5 mm/s each
    v[26:32, 0, 0] = -0.0048           # and back
    rest = run(v)[:, 0]
    assert rest[11:24].all()           # 0.8 mm out at index 23 (index 24: 1.0 mm, the limit itself)
    assert not rest[25:32].any()       # windows from a point at 0 mm to the 1.2 mm one (index 25)
    assert rest[33:36].all()           # windows from 0.4-0.8 mm out: the path within 0.8 mm of it
    assert not rest[37]                # the window from the 1.2 mm point back to 0 mm
    assert rest[40:].all()             # windows from 0.4 mm on the way back or later


def creeping(velocities: np.ndarray) -> np.ndarray:
    """As `run`, but returns frames x n `creeping()` flags (below the speed limit over the window)."""
    return _feed(velocities, lambda test, rest: test.creeping())


def test_a_slow_slide_creeps_a_fast_one_does_not():
    """What may end a drop stage before the last: body 0 slides at 2.5 mm/s (1.25 mm per window:
    not at rest, but under the 5 mm/s speed limit at every frame: creeping from the window's 12th
    frame on); body 1 at 6 mm/s is neither; body 2 at rest is both."""
    v = np.zeros((40, 3, 3))
    v[:, 0, 0], v[:, 1, 0] = 0.0025, 0.006
    c, rest = creeping(v), run(v)
    assert not c[:11].any() and c[11:, 0].all() and not rest[:, 0].any()
    assert not c[:, 1].any() and not rest[:, 1].any()
    assert c[11:, 2].all() and rest[11:, 2].all()
