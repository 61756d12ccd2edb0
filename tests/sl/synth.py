"""Analytic ray casting of synthetic structured-light scenes: the tests' ground truth.

Independent of the decoder: everything here is float64 ray/primitive intersection; fringe images
are the pattern formula of docs/CONVENTIONS.md evaluated at the exact (continuous) projector coordinate of
each camera pixel's surface point, times an albedo, so no pattern image is sampled. Only
``projection_matrix``/``intrinsics`` conventions are shared (pixel centres at integers, OpenCV
frames) and those are tested on their own.

World: z up. The standard rig has the camera at height ``distance`` looking straight down, the
projector ``baseline`` to the camera's right (camera +x), converging on the origin.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

TWO_PI = 2 * np.pi


# ------------------------------------------------------------------ devices
def look_at(eye, target, down=(0.0, -1.0, 0.0)) -> np.ndarray:
    """4x4 pose (OpenCV frame: z forward, y down) of a device at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    y_hint = np.asarray(down, float)
    x = np.cross(y_hint, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


@dataclass
class Device:
    K: np.ndarray
    T: np.ndarray            # pose in world (OpenCV frame)
    size: tuple              # (width, height)

    @property
    def P(self) -> np.ndarray:
        Tinv = np.linalg.inv(self.T)
        return self.K @ Tinv[:3]

    @property
    def centre(self) -> np.ndarray:
        return self.T[:3, 3].copy()

    def rays(self, ss: int = 1, offset=(0.0, 0.0)):
        """World ray directions (H, W, 3) with camera-frame z = 1 (t = planar depth)."""
        w, h = self.size
        u = np.arange(w, dtype=float) + offset[0]
        v = np.arange(h, dtype=float) + offset[1]
        uu, vv = np.meshgrid(u, v)
        pix = np.stack([uu, vv, np.ones_like(uu)], -1)
        d_cam = pix @ np.linalg.inv(self.K).T
        return d_cam @ self.T[:3, :3].T

    def project(self, X):
        """World points (..., 3) -> pixel (..., 2) and device-frame depth (...)."""
        Tinv = np.linalg.inv(self.T)
        Xc = X @ Tinv[:3, :3].T + Tinv[:3, 3]
        p = Xc @ self.K.T
        return p[..., :2] / p[..., 2:3], Xc[..., 2]


def intrinsics(f, size):
    w, h = size
    return np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])


def make_rig(cam_size=(160, 120), proj_size=(512, 384), f_cam=None, f_proj=None, baseline=0.15,
             distance=1.0, converge=True, proj_offset=None, target=(0.0, 0.0, 0.0)):
    """Camera looking down from ``distance``; projector displaced by ``baseline`` along camera +x
    (or by the camera-frame vector ``proj_offset``), aimed at ``target`` when ``converge``."""
    f_cam = f_cam if f_cam is not None else 1.25 * cam_size[0]
    f_proj = f_proj if f_proj is not None else 1.2 * proj_size[0]
    Tc = look_at((0.0, 0.0, distance), target)
    cam = Device(intrinsics(f_cam, cam_size), Tc, tuple(cam_size))
    off = np.array([baseline, 0.0, 0.0]) if proj_offset is None else np.asarray(proj_offset, float)
    eye = Tc[:3, :3] @ off + Tc[:3, 3]
    if converge:
        Tp = look_at(eye, target, down=Tc[:3, 1])
    else:
        Tp = Tc.copy()
        Tp[:3, 3] = eye
    proj = Device(intrinsics(f_proj, proj_size), Tp, tuple(proj_size))
    return cam, proj


# ------------------------------------------------------------------ primitives
@dataclass
class Plane:
    point: tuple
    normal: tuple
    albedo: float = 1.0

    def intersect(self, o, d):
        n = np.asarray(self.normal, float)
        n = n / np.linalg.norm(n)
        denom = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((np.asarray(self.point, float) - o) @ n) / denom
        t = np.where(np.abs(denom) > 1e-15, t, np.inf)
        nn = np.broadcast_to(n, d.shape)
        return t, nn


@dataclass
class Sphere:
    centre: tuple
    radius: float
    albedo: float = 1.0

    def intersect(self, o, d):
        c = np.asarray(self.centre, float)
        oc = o - c
        a = np.sum(d * d, -1)
        b = 2 * np.sum(oc * d, -1)
        cc = np.sum(oc * oc, -1) - self.radius ** 2
        disc = b * b - 4 * a * cc
        sq = np.sqrt(np.maximum(disc, 0))
        t1 = (-b - sq) / (2 * a)
        t2 = (-b + sq) / (2 * a)
        t = np.where(t1 > 1e-9, t1, t2)
        t = np.where((disc >= 0) & (t > 1e-9), t, np.inf)
        X = o + t[..., None] * d
        n = (X - c) / self.radius
        return t, n


@dataclass
class Box:
    lo: tuple
    hi: tuple
    albedo: float = 1.0

    def _slabs(self, o, d):
        """Per axis, the ray parameters where o + t d enters and leaves the box's slab (NaN where the
        ray runs in a slab's plane)."""
        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t0 = (lo - o) * inv
            t1 = (hi - o) * inv
        return np.minimum(t0, t1), np.maximum(t0, t1)

    def intersect(self, o, d):
        tmin, tmax = self._slabs(o, d)
        tmin = np.where(np.isnan(tmin), -np.inf, tmin)
        tmax = np.where(np.isnan(tmax), np.inf, tmax)
        tn = np.max(tmin, -1)
        tf = np.min(tmax, -1)
        hit = (tn <= tf) & (tf > 1e-9)
        t = np.where(hit, np.where(tn > 1e-9, tn, tf), np.inf)
        axis = np.argmax(tmin, -1)
        n = np.zeros(d.shape)
        sgn = -np.sign(np.take_along_axis(d, axis[..., None], -1))[..., 0]
        np.put_along_axis(n, axis[..., None], sgn[..., None], -1)
        return t, n

    def segment_hits(self, o, d, smax):
        """True where the segment o + s d, s in (eps, smax*(1-1e-9)), passes through the box."""
        tmin, tmax = self._slabs(o, d)
        tmin = np.nan_to_num(tmin, nan=-np.inf)
        tmax = np.nan_to_num(tmax, nan=np.inf)
        tn = np.max(tmin, -1)
        tf = np.min(tmax, -1)
        return (tn < tf) & (tn < smax * (1 - 1e-7)) & (tf > 1e-9)


@dataclass
class Scene:
    prims: list = field(default_factory=list)
    patches: list = field(default_factory=list)   # (primitive index, lo xyz, hi xyz, albedo): albedo of the
                                                  # primitive's surface points inside that world box

    def cast(self, o, d):
        """Nearest hit: t (inf = none), primitive index, normal."""
        best = np.full(d.shape[:-1], np.inf)
        idx = np.full(d.shape[:-1], -1)
        nrm = np.zeros(d.shape)
        for i, p in enumerate(self.prims):
            t, n = p.intersect(o, d)
            closer = t < best
            best = np.where(closer, t, best)
            idx = np.where(closer, i, idx)
            nrm = np.where(closer[..., None], n, nrm)
        return best, idx, nrm

    def occluded(self, o, X):
        """Is the segment from point o to points X blocked by any primitive (before X)?"""
        d = X - o
        blocked = np.zeros(X.shape[:-1], bool)
        for p in self.prims:
            if isinstance(p, Box):
                blocked |= p.segment_hits(o, d, 1.0)
            else:
                t, _ = p.intersect(o, d)
                blocked |= t < 1.0 - 1e-7
        return blocked


# ------------------------------------------------------------------ scenes
def plane_scene(height=0.0, albedo=1.0):
    return Scene([Plane((0, 0, height), (0, 0, 1), albedo)])


def tilted_plane_scene(angle_deg, axis="y", albedo=1.0):
    a = np.radians(angle_deg)
    n = (np.sin(a), 0.0, np.cos(a)) if axis == "y" else (0.0, np.sin(a), np.cos(a))
    return Scene([Plane((0, 0, 0), n, albedo)])


def sphere_scene(radius=0.15, albedo=1.0):
    return Scene([Plane((0, 0, 0), (0, 0, 1), albedo), Sphere((0, 0, radius), radius, albedo)])


def box_scene(size=0.2, height=0.15, albedo=1.0, centre=(0.0, 0.0)):
    cx, cy = centre
    return Scene([Plane((0, 0, 0), (0, 0, 1), albedo),
                  Box((cx - size / 2, cy - size / 2, 0.0), (cx + size / 2, cy + size / 2, height), albedo)])


def dark_step_scene():
    """The adversarial scene of issue #19: a floor tilted by 8 degrees, two boxes whose tops stand
    0.13 m and 0.25 m above it (depth steps, projector shadows beside them), two spheres, a floor
    patch of albedo 0.015 and the high box's top at albedo 0.04 (dark patches beside depth steps);
    the rest albedo 0.5-0.7. Sized for ``make_rig(distance=1.0)`` (0.8 x 0.6 m in view)."""
    a = np.radians(8.0)
    floor = Plane((0, 0, 0), (np.sin(a), 0.0, np.cos(a)), 0.5)
    zf = lambda x: -np.tan(a) * x                     # floor height at x (y-independent)
    low = Box((-0.26, -0.2, zf(-0.06) - 0.05), (-0.06, 0.0, zf(-0.06) + 0.13), 0.6)
    high = Box((0.04, -0.05, zf(0.2) - 0.05), (0.2, 0.17, zf(0.2) + 0.25), 0.6)
    s1 = Sphere((-0.2, 0.16, zf(-0.2) + 0.05), 0.07, 0.7)
    s2 = Sphere((0.29, -0.17, zf(0.29) + 0.04), 0.06, 0.7)
    top = zf(0.2) + 0.25
    return Scene([floor, low, high, s1, s2],
                 patches=[(0, (-0.05, -0.26, -1.0), (0.01, -0.2, 1.0), 0.015),
                          (2, (0.04, -0.05, top - 1e-6), (0.2, 0.17, top + 1e-6), 0.04)])


def sensor_stack(render, *, full_scale=250.0, read=1.0, e_per_dn=40.0, seed=0, dtype=np.float32):
    """A render's images in DN (``full_scale`` x radiance) with read + shot noise: Gaussian of
    variance ``read^2 + I / e_per_dn`` per sample of mean ``I`` DN (the normal limit of Poisson
    shot noise at ``e_per_dn`` electrons per DN), not quantised. The true per-pixel
    noise model is ``lambda A: sqrt(read^2 + A / e_per_dn)``."""
    rng = np.random.default_rng(seed)
    mean = render.images * full_scale if hasattr(render, "images") else np.asarray(render) * full_scale
    noisy = mean + rng.standard_normal(mean.shape) * np.sqrt(read ** 2 + mean / e_per_dn)
    return noisy.astype(dtype)


# ------------------------------------------------------------------ rendering
@dataclass
class Render:
    images: np.ndarray      # (F*N, H, W) float64
    depth: np.ndarray       # planar depth, NaN where no surface
    proj_x: np.ndarray      # projector coordinate along the coded axis, NaN where unlit
    lit: np.ndarray         # surface lit by the projector (inside its image, not shadowed, facing)
    shadow: np.ndarray      # surface inside the projector frustum but occluded (projector shadow)
    points: np.ndarray      # camera-frame points (H, W, 3)
    albedo: np.ndarray


def _surface(scene, cam, proj, offset=(0.0, 0.0)):
    o = cam.centre
    d = cam.rays(offset=offset)
    t, idx, n = scene.cast(np.broadcast_to(o, d.shape), d)
    hit = np.isfinite(t)
    X = o + np.where(hit, t, 0.0)[..., None] * d
    alb = np.zeros(t.shape)
    for i, p in enumerate(scene.prims):
        alb[idx == i] = p.albedo
    for i, lo, hi, a in scene.patches:
        alb[(idx == i) & np.all((X >= np.asarray(lo, float)) & (X <= np.asarray(hi, float)), -1)] = a
    pxy, zp = proj.project(X)
    w, h = proj.size
    inside = hit & (zp > 0) & (pxy[..., 0] >= -0.5) & (pxy[..., 0] <= w - 0.5) \
        & (pxy[..., 1] >= -0.5) & (pxy[..., 1] <= h - 0.5)
    to_proj = proj.centre - X
    to_cam = o - X
    facing = (np.sum(n * to_proj, -1) > 0) & (np.sum(n * to_cam, -1) > 0)
    occl = scene.occluded(np.broadcast_to(proj.centre, X.shape), X) & hit
    lit = inside & facing & ~occl
    shadow = hit & inside & ~lit
    return t, hit, X, pxy, lit, shadow, alb


def render(scene, cam, proj, periods, steps, *, a=0.5, b=0.5, ambient=0.0, axis="x",
           supersample=1, shifts=None, gamma=None, projector_gamma=1.0):
    """Fringe images and ground truth. ``supersample`` s averages s x s point samples per pixel
    (pixel area integration); ground truth is at the pixel centre. ``gamma``: a camera tone curve
    ``I ** (1/gamma)``; ``projector_gamma``: the projector emits ``pattern ** projector_gamma``."""
    w, h = proj.size
    length = w if axis == "x" else h
    shifts = TWO_PI * np.arange(steps) / steps if shifts is None else np.asarray(shifts, float)
    t, hit, X, pxy, lit, shadow, alb = _surface(scene, cam, proj)
    if supersample == 1:
        samples = [(pxy, lit, alb, hit)]
    else:
        samples = []
        offs = (np.arange(supersample) + 0.5) / supersample - 0.5
        for oy in offs:
            for ox in offs:
                _, hs, _, pxs, ls, _, als = _surface(scene, cam, proj, offset=(ox, oy))
                samples.append((pxs, ls, als, hs))
    imgs = np.zeros((len(periods) * steps,) + t.shape)
    for pxs, ls, als, hs in samples:
        c = pxs[..., 0] if axis == "x" else pxs[..., 1]
        for i, k in enumerate(periods):
            for n in range(steps):
                val = (a + b * np.cos(TWO_PI * k * c / length + shifts[n])) ** projector_gamma
                imgs[i * steps + n] += als * (np.where(ls, val, 0.0) + ambient * hs)
    imgs /= len(samples)
    if gamma is not None:
        imgs = np.clip(imgs, 0, None) ** (1.0 / gamma)
    Tinv = np.linalg.inv(cam.T)
    pts = X @ Tinv[:3, :3].T + Tinv[:3, 3]
    depth = np.where(hit, pts[..., 2], np.nan)
    coord = pxy[..., 0] if axis == "x" else pxy[..., 1]
    return Render(images=imgs, depth=depth, proj_x=np.where(lit, coord, np.nan), lit=lit, shadow=shadow,
                  points=np.where(hit[..., None], pts, np.nan), albedo=alb)


def depth_slope(cam, proj, depth, axis="x", dz=1e-6):
    """|dZ/dx| (metres per projector pixel) along each camera ray at ``depth``, by central
    differences of the analytic projection (float64) -- independent of the decoder's formula."""
    o = cam.centre
    d = cam.rays()
    z = np.where(np.isfinite(depth), depth, 1.0)
    j = 0 if axis == "x" else 1
    x1 = proj.project(o + (z + dz)[..., None] * d)[0][..., j]
    x0 = proj.project(o + (z - dz)[..., None] * d)[0][..., j]
    with np.errstate(divide="ignore"):
        return np.abs(2 * dz / (x1 - x0))


def fringes(render, periods, steps, proj_length, *, a=0.5, b=0.5, ambient=0.0, dtype=np.float64):
    """Re-evaluate the pattern formula on a render's ground-truth coordinates (point sampling,
    pixel centres) for another set of periods/steps: cheap for benchmarks sweeping configurations."""
    c = np.where(render.lit, render.proj_x, 0.0)
    alb = render.albedo
    lit = render.lit
    hit = np.isfinite(render.depth)
    shifts = TWO_PI * np.arange(steps) / steps
    out = np.empty((len(periods) * steps,) + c.shape, dtype)
    for i, k in enumerate(periods):
        base = TWO_PI * k * c / proj_length
        for n in range(steps):
            out[i * steps + n] = alb * (np.where(lit, a + b * np.cos(base + shifts[n]), 0.0) + ambient * hit)
    return out


# ------------------------------------------------------------------ real cameras' tone curves
def srgb_encode(lin):
    """The sRGB transfer function (IEC 61966-2-1: 12.92 L up to L = 0.0031308, else
    1.055 L^(1/2.4) - 0.055), the tone curve of a colour camera's image processor when nothing else
    is known. On fringes a + b cos of albedo 0.1-0.8 over ambient 0.02-0.2 it makes 2nd harmonics
    of 11-17% of the fundamental, 3rd 2-5%, 4th 0.5-2% (a 4096-sample FFT of the curve)."""
    lin = np.clip(lin, 0.0, 1.0)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)


def tone_curve_stack(render, curve, *, full_scale=255.0, ambient=0.05, noise_dn=1.5, seed=0,
                     noise_before_curve=False):
    """uint8 camera images of a render through a tone curve: linear radiance ``albedo * pattern +
    ambient * albedo`` (clipped to [0, 1]) -> ``curve`` -> ``full_scale`` DN, Gaussian noise of
    ``noise_dn`` DN added after the curve (an image processor's output noise; with
    ``noise_before_curve`` it is added to the linear signal, scaled to ``noise_dn`` DN at full
    scale) and rounding. Returns (images, true noise sigma in DN of the output, incl. the 1/12 DN^2
    of rounding; for noise before the curve: an (F*N, H, W) map of each sample's sigma)."""
    rng = np.random.default_rng(seed)
    lin = render.images + ambient * render.albedo * np.isfinite(render.depth)
    if noise_before_curve:
        lin_n = lin + rng.standard_normal(lin.shape) * (noise_dn / full_scale)
        out = full_scale * curve(lin_n)
        eps = 1e-4
        slope = (curve(np.clip(lin + eps, 0, 1)) - curve(np.clip(lin - eps, 0, 1))) / (2 * eps)
        true = np.sqrt((slope * noise_dn) ** 2 + 1 / 12)
    else:
        out = full_scale * curve(lin) + rng.standard_normal(lin.shape) * noise_dn
        true = float(np.sqrt(noise_dn ** 2 + 1 / 12))
    return np.clip(np.rint(out), 0, 255).astype(np.uint8), true


def dark_patch_albedo(shape):
    """Albedo 0.8 with a vertical ramp 0.04 -> 0.8 on the left quarter and five dark patches
    (0.04-0.15), laid out on a 320 x 240 frame and scaled to `shape` (H, W): the dark-region stacks of
    tests/sl/test_sl_coverage.py (160 x 120) and benchmarks/bench_sl_coverage.py (320 x 240)."""
    H, W = shape
    sy, sx = H / 240, W / 320
    a = np.full(shape, 0.8)
    a[:, :W // 4] = np.linspace(0.04, 0.8, H)[:, None]
    for r0, c0, v in [(20, 100, 0.04), (20, 190, 0.06), (130, 100, 0.1), (130, 190, 0.15), (80, 260, 0.04)]:
        r, c = round(r0 * sy), round(c0 * sx)
        a[r:r + round(60 * sy), c:c + round(56 * sx)] = v
    return a
