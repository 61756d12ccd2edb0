"""Lens distortion: OpenCV's model, its inverse, the render grid that covers a distorted image and the
remap from that grid to the camera's image. No bpy (core/camera.py and core/renderer.py use it,
sl/ and io/ read its numbers); docs/CALIBRATION.md explains the choices.

The model is OpenCV's ("Camera Calibration and 3D Reconstruction", calib3d, docs.opencv.org/4.x/
d9/d0c/group__calib3d.html): for a point with normalised coordinates (x, y) = (X/Z, Y/Z) and
r^2 = x^2 + y^2,

    x'' = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
    y'' = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y
    u = fx x'' + cx,  v = fy y'' + cy

with the coefficients in OpenCV's order (k1, k2, p1, p2, k3). The image a distorted camera takes is
made by rendering an ideal pinhole camera (`RenderGrid`: square pixels, wide enough to hold every
ray of the distorted image, at least as fine as the image everywhere) and looking each image pixel's
ray up in that render (`RenderGrid.remap`): a cubic spline for radiance (RGB, fringes), the nearest
render pixel for everything that must not be blended (ids, depth, normals, coordinates).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import Problem

MARGIN_PX = 8              # render pixels beyond the outermost ray on each side: the spline's boundary
                           # error decays as 0.27^n px inward (8 px: 3e-5 of the edge step)
MAX_RENDER_AREA = 4.0      # a render grid may hold at most 4x the image's pixels
NEWTON_STEPS = 20
NEWTON_TOL = 1e-12         # normalised units (1e-12 x a focal length of 1e4 px = 1e-8 px)


def coefficients(d) -> np.ndarray | None:
    """(k1, k2, p1, p2, k3) as float64, or None when `d` is None or all zero (no distortion: the
    camera renders as it always did)."""
    if d is None:
        return None
    a = np.asarray(d, dtype=np.float64).reshape(-1)
    return None if not np.any(a) else a


def distort(x, y, d):
    """Normalised ideal (x, y) -> normalised distorted (x'', y'') by OpenCV's model."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def jacobian(x, y, d):
    """d(x'', y'')/d(x, y) as four arrays (a = dx''/dx, b = dx''/dy, c = dy''/dx, e = dy''/dy)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)            # d radial / d r^2
    a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    c = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    e = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return a, b, c, e


def undistort(xd, yd, d):
    """Normalised distorted (x'', y'') -> ideal (x, y): Newton's method on the forward model
    (quadratic convergence; OpenCV's undistortPoints uses a fixed-point iteration with 5 steps by
    default, too few for strong lenses). Returns (x, y, residual) with the residual in normalised
    units; callers check it (a folding lens has no unique inverse)."""
    xd = np.asarray(xd, dtype=np.float64)
    yd = np.asarray(yd, dtype=np.float64)
    x, y = xd.copy(), yd.copy()
    for _ in range(NEWTON_STEPS):
        fx, fy = distort(x, y, d)
        rx, ry = fx - xd, fy - yd
        a, b, c, e = jacobian(x, y, d)
        det = a * e - b * c
        with np.errstate(divide="ignore", invalid="ignore"):
            x = x - (e * rx - b * ry) / det
            y = y - (a * ry - c * rx) / det
        if np.nanmax(np.abs(rx) + np.abs(ry), initial=0.0) < NEWTON_TOL:
            break
    fx, fy = distort(x, y, d)
    return x, y, np.hypot(fx - xd, fy - yd)


def _frame_border(K, size, step: float = 4.0):
    """Distorted normalised coordinates of points along the image's outer pixel edges."""
    w, h = size
    us = np.concatenate([np.arange(-0.5, w - 0.5, step), [w - 0.5]])
    vs = np.concatenate([np.arange(-0.5, h - 0.5, step), [h - 0.5]])
    u = np.concatenate([us, us, np.full(vs.size, -0.5), np.full(vs.size, w - 0.5)])
    v = np.concatenate([np.full(us.size, -0.5), np.full(us.size, h - 0.5), vs, vs])
    return (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]


def turning_radius(d) -> float:
    """The ideal radius where r'' = r (1 + k1 r^2 + k2 r^4 + k3 r^6) stops growing (inf if never, up
    to r = 10): beyond it the polynomial no longer describes a lens."""
    k1, k2, _, _, k3 = d
    r = np.linspace(0.0, 10.0, 100001)
    r2 = r * r
    turn = np.flatnonzero(1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + 7.0 * k3 * r2)) <= 0)
    return float(r[turn[0]]) if turn.size else math.inf


def fold_problem(K, d, size, path: str = "camera.distortion") -> Problem | None:
    """A Problem when the lens folds the image: the radius r'' = r (1 + k1 r^2 + k2 r^4 + k3 r^6)
    stops growing before it reaches the frame's farthest corner (two rays would land on one pixel),
    or the full model (with the tangential terms) is not invertible somewhere in the frame."""
    d = coefficients(d)
    if d is None:
        return None
    K = np.asarray(K, dtype=np.float64)
    k1, k2, p1, p2, k3 = d
    xb, yb = _frame_border(K, size)
    rd_max = float(np.hypot(xb, yb).max())
    r = np.linspace(0.0, 4.0 * max(rd_max, 1e-6) + 1.0, 200001)
    r2 = r * r
    rd = r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
    slope = 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + 7.0 * k3 * r2))
    turn = np.flatnonzero(slope <= 0)
    reach = np.flatnonzero(rd >= rd_max)
    if turn.size and (not reach.size or turn[0] <= reach[0]):
        return Problem(path, f"the distortion {list(map(float, d))} folds the image: the distorted radius "
                       f"stops growing at r = {r[turn[0]]:.3g} (r'' = {rd[turn[0]]:.3g}), inside the frame "
                       f"(its corners are at r'' = {rd_max:.3g})",
                       "check the coefficients' order (OpenCV: k1 k2 p1 p2 k3) and sign; a calibration "
                       "whose polynomial turns inside the frame is over-fitted: recalibrate with "
                       "views that cover the image corners")
    if not reach.size:
        return Problem(path, f"the distortion {list(map(float, d))} never reaches the frame's corners "
                       f"(r'' = {rd_max:.3g})", "check the coefficients' order (OpenCV: k1 k2 p1 p2 k3)")
    # the whole map, tangential terms included: every frame pixel has exactly one ray
    w, h = size
    uu, vv = np.meshgrid(np.linspace(-0.5, w - 0.5, 65), np.linspace(-0.5, h - 0.5, 49))
    x, y, res = undistort((uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], d)
    a, b, c, e = jacobian(x, y, d)
    if not np.all(np.isfinite(res)) or res.max() > 1e-9 or np.any(a * e - b * c <= 0):
        return Problem(path, f"the distortion {list(map(float, d))} is not invertible inside the frame "
                       "(the tangential terms p1 p2 fold it)", "check p1 and p2 (OpenCV order: k1 k2 p1 p2 k3)")
    return None


@dataclass(frozen=True)
class RenderGrid:
    """The ideal pinhole that is rendered for a camera with intrinsics `K` (any fx, fy, cx, cy) and
    distortion `d` at `size` (W, H): square pixels of focal length `f` px, `render_size` pixels,
    principal point (cx, cy) of `K_render`. With no distortion and fx = fy it is the camera itself."""
    K: np.ndarray
    d: np.ndarray | None
    size: tuple[int, int]
    K_render: np.ndarray
    render_size: tuple[int, int]

    @property
    def identity(self) -> bool:
        return (self.d is None and self.render_size == self.size and np.array_equal(self.K, self.K_render))

    def maps(self) -> tuple[np.ndarray, np.ndarray]:
        """(map_x, map_y), float64 (H, W): the render pixel coordinates each image pixel's ray hits."""
        cached = _MAPS.get(self._key())
        if cached is not None:
            return cached
        x, y = self.ideal_normalised()
        Kr = self.K_render
        maps = (Kr[0, 0] * x + Kr[0, 2], Kr[1, 1] * y + Kr[1, 2])
        _MAPS.clear()                                # one camera per run: keep the last only
        _MAPS[self._key()] = maps
        return maps

    def ideal_normalised(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) float64 ideal normalised coordinates (X/Z, Y/Z) of each image pixel's ray (solved once
        per camera and kept: ~10 s for 2448 x 2048 on one core; the renderer, the fringes and the
        decoder share it)."""
        cached = _IDEAL.get(self._key())
        if cached is None:
            cached = self._solve_ideal()
            _IDEAL.clear()                           # one camera per run: keep the last only
            _IDEAL[self._key()] = cached
        return cached[0].copy(), cached[1].copy()

    def _solve_ideal(self) -> tuple[np.ndarray, np.ndarray]:
        w, h = self.size
        K = self.K
        xd = (np.arange(w, dtype=np.float64)[None, :] - K[0, 2]) / K[0, 0]
        yd = (np.arange(h, dtype=np.float64)[:, None] - K[1, 2]) / K[1, 1]
        xd, yd = np.broadcast_arrays(xd, yd)
        if self.d is None:
            return xd.copy(), yd.copy()
        x, y, _ = undistort(xd, yd, self.d)
        return x, y

    def ideal_pixels(self) -> np.ndarray:
        """(H, W, 2) float64: where each image pixel's ray would land in an undistorted camera with
        the same K; what the decoder triangulates with (`sl.Triangulator(..., pixels=)`)."""
        x, y = self.ideal_normalised()
        K = self.K
        return np.stack([K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2]], axis=-1)

    def remap(self, img: np.ndarray, *, linear: bool) -> np.ndarray:
        """A render (H_r, W_r[, C]) or a stack (F, H_r, W_r) -> the camera's image.

        `linear` (radiance: RGB before its sRGB encoding, fringe images): a cubic B-spline through the
        render's pixels, evaluated at each ray's exact (float64) render coordinates, negative
        overshoot clipped (radiance is >= 0). Measured on the plane of tests/blender/
        test_lens_distortion.py (finest fringe ~5 px): bilinear interpolation, and cv2.remap (which
        rounds its map to 1/32 px), bend the phase of such fringes by up to a few hundredths of a
        period, 2.5x the scanner's depth noise; the spline keeps it at 1.07x, as a pinhole render
        without remap (1.06x). Otherwise (ids, depth, normals, coordinates): the nearest render
        pixel, a value of a real surface, never a blend of two."""
        if self.identity:
            return img
        a = np.asarray(img)
        wr, hr = self.render_size
        if a.shape[:2] == (hr, wr):
            stack = False
        elif a.ndim == 3 and a.shape[1:] == (hr, wr):
            stack = True
        else:
            raise ValueError(f"remap: image of shape {a.shape} is not the render grid's {(hr, wr)}")
        mx, my = self.maps()
        if not linear:
            ix = np.clip(np.rint(mx), 0, wr - 1).astype(np.intp)
            iy = np.clip(np.rint(my), 0, hr - 1).astype(np.intp)
            return a[:, iy, ix] if stack else a[iy, ix]
        from scipy import ndimage
        planes = list(a) if stack else [a] if a.ndim == 2 else [a[..., i] for i in range(a.shape[2])]
        out = [np.maximum(ndimage.map_coordinates(p.astype(np.float64), [my, mx], order=3, mode="nearest"), 0.0)
               .astype(a.dtype) for p in planes]
        return np.stack(out) if stack else out[0] if a.ndim == 2 else np.stack(out, axis=-1)

    def _key(self):
        return (self.K.tobytes(), None if self.d is None else self.d.tobytes(), self.size)


_MAPS: dict = {}
_IDEAL: dict = {}


def render_grid(K, d, size) -> RenderGrid:
    """The render grid of a camera (see RenderGrid). Its focal length is max(fx, fy) times the lens's
    largest local stretch (so no image pixel is finer than a render pixel); it spans every ray of the
    image plus MARGIN_PX pixels on each side."""
    K = np.asarray(K, dtype=np.float64)
    d = coefficients(d)
    w, h = (int(v) for v in size)
    if d is None and K[0, 0] == K[1, 1]:
        return RenderGrid(K, None, (w, h), K, (w, h))
    f = max(K[0, 0], K[1, 1])
    if d is not None:
        uu, vv = np.meshgrid(np.linspace(-0.5, w - 0.5, 33), np.linspace(-0.5, h - 0.5, 25))
        x, y, _ = undistort((uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], d)
        a, b, c, e = jacobian(x, y, d)
        # an image pixel spans 1/(f s) of ideal angle along the Jacobian's singular directions: the
        # largest singular value (a pincushion's stretched corners) sets the finest render pitch needed
        s_max = 0.5 * (np.hypot(a + e, c - b) + np.hypot(a - e, c + b))
        f = f * max(1.0, float(s_max.max()))
        xb, yb = _frame_border(K, (w, h), step=1.0)
        xb, yb, _ = undistort(xb, yb, d)
    else:
        xb, yb = _frame_border(K, (w, h), step=1.0)
    x0, x1, y0, y1 = xb.min(), xb.max(), yb.min(), yb.max()
    wr = int(math.ceil(f * (x1 - x0))) + 2 * MARGIN_PX
    hr = int(math.ceil(f * (y1 - y0))) + 2 * MARGIN_PX
    Kr = np.array([[f, 0.0, MARGIN_PX - 0.5 - f * x0], [0.0, f, MARGIN_PX - 0.5 - f * y0], [0.0, 0.0, 1.0]])
    return RenderGrid(K, d, (w, h), Kr, (wr, hr))


def render_area_problem(grid: RenderGrid, path: str = "camera.distortion") -> Problem | None:
    """A Problem when the render grid would cost more than MAX_RENDER_AREA x the image's pixels."""
    ratio = grid.render_size[0] * grid.render_size[1] / float(grid.size[0] * grid.size[1])
    if ratio > MAX_RENDER_AREA:
        return Problem(path, f"the lens needs a render of {grid.render_size[0]} x {grid.render_size[1]} px to "
                       f"make the {grid.size[0]} x {grid.size[1]} image ({ratio:.1f}x the pixels, at most "
                       f"{MAX_RENDER_AREA:g}x)", "check the coefficients (OpenCV order k1 k2 p1 p2 k3) and "
                       "camera.intrinsics; a fisheye lens needs a fisheye model, which DataPipe does not have")
    return None


def blender_shift(grid: RenderGrid) -> tuple[float, float]:
    """Blender's (shift_x, shift_y) for the render grid's principal point with sensor fit AUTO
    (shift in units of the larger image dimension; +shift_y moves the view up, the principal
    point down): the inverse of geometry.intrinsics_from_blender_camera."""
    wr, hr = grid.render_size
    size = max(wr, hr)
    Kr = grid.K_render
    return (wr / 2.0 - 0.5 - Kr[0, 2]) / size, (Kr[1, 2] - (hr / 2.0 - 0.5)) / size
