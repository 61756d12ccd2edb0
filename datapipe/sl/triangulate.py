"""Camera-projector triangulation in closed form (the camera-model helpers it re-exports,
`intrinsics_from_blender_camera` and `projection_matrix`, live in datapipe.geometry).

Geometry. ``P_cam = K [R|t]`` and ``P_proj`` are 3x4 world -> pixel matrices (OpenCV convention,
pixel centres at integers). ``P_cam`` is normalised (sign and scale) so that for a world point X,
``P_cam X = Z (u, v, 1)`` with ``Z`` the planar depth in the camera frame. Eliminating X::

    X = M^-1 (Z m - p4),  m = (u, v, 1),  [M | p4] = P_cam
    P_proj X = Z alpha(u, v) + beta,   alpha = H m,  H = M_p M^-1,  beta = p_p4 - H p4

so the projector column ``x = (Z a0 + b0) / (Z a2 + b2)`` and, inverted, depth is a rational
function of x with per-pixel coefficients (computed once in float64, stored in float32)::

    Z = (b0 - b2 x) / (a2 x - a0)  =  (b0 - b2 x) / (x - xinf) / a2,   xinf = a0/a2

``a0, a2`` are per pixel, ``b0, b2`` constants; the second form (see
:attr:`Triangulator.coefficients`) is the one evaluated, in float32. Conditioning: with ``Zp = Z a2 + b2`` (the
point's depth in the projector frame) and ``q = b0 a2 - b2 a0``,
``dZ/dx = Zp^2 / q`` (magnitude), metres of depth per projector pixel. ``q = 0`` means the
camera ray lies in one projector column plane (no depth information at all); pixels whose
``|dZ/dx|`` exceeds a cap are flagged ill-conditioned, and ``|dZ/dx| * sigma_x`` is the depth
uncertainty of a pixel (see :meth:`Triangulator.depth_slope`).
"""
from __future__ import annotations

import warnings
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..geometry import finite_matrix as _finite_matrix
from ..geometry import intrinsics_from_blender_camera, projection_matrix
from ._errors import bad_type, bad_value

__all__ = ["Triangulator", "TriangulationResult", "intrinsics_from_blender_camera", "intrinsics_from_blender",
           "projection_matrix"]


def intrinsics_from_blender(focal_mm: float, sensor_width_mm: float, width: int, height: int,
                            sensor_fit: str = "AUTO", *, sensor_height_mm: float = 24.0,
                            shift_x: float = 0.0, shift_y: float = 0.0) -> np.ndarray:
    """Deprecated alias of `intrinsics_from_blender_camera` (removed in DataPipe 0.2.0; docs/API.md,
    "Deprecations"), kept because ``datapipe.sl`` 0.1.0 exported it: same arguments, same defaults (a
    VERTICAL fit uses ``sensor_height_mm``, 24 mm unless given, as a real Blender camera does), same
    result. For DataPipe configs' one-sensor-size convention use
    `datapipe.geometry.intrinsics_from_sensor`."""
    warnings.warn("datapipe.sl.intrinsics_from_blender is deprecated and will be removed in DataPipe 0.2.0: "
                  "use datapipe.sl.intrinsics_from_blender_camera (the same arguments and result)",
                  DeprecationWarning, stacklevel=2)
    return intrinsics_from_blender_camera(focal_mm, sensor_width_mm, width, height, sensor_fit,
                                          sensor_height_mm=sensor_height_mm, shift_x=shift_x, shift_y=shift_y)


def _size(s, name):
    try:
        w, h = (int(v) for v in s)
    except (TypeError, ValueError):
        raise bad_type(name, f"must be (width, height), got {s!r}", "pass a pair of ints") from None
    if w < 1 or h < 1:
        raise bad_value(name, f"must be positive, got {s!r}", "pass (width, height) in pixels")
    return w, h


def _normalise_camera(P, name):
    """Scale P so that its third row's rotation part has unit norm and det(M) > 0."""
    M = P[:, :3]
    det = np.linalg.det(M)
    n3 = np.linalg.norm(M[2])
    if abs(det) < 1e-12 * max(1.0, np.linalg.norm(M)) ** 3 or n3 == 0:
        raise bad_value(name, "is singular (its left 3x3 block has no inverse)",
                        "build it as K @ [R | t] with a proper rotation and focal length > 0")
    return P * (np.sign(det) / n3)


# --------------------------------------------------------------------------------------------
# triangulation
# --------------------------------------------------------------------------------------------

@dataclass
class TriangulationResult:
    depth: np.ndarray        # (H, W) float32, NaN where not ok
    points: np.ndarray       # (H, W, 3) float32 camera frame, NaN where not ok
    ill_conditioned: np.ndarray   # bool
    outside: np.ndarray      # bool: behind the projector or outside its other image axis


class Triangulator:
    """Closed-form depth from a projector coordinate per camera pixel.

    ``Triangulator(P_cam, P_proj, cam_size, proj_size, axis='x')``; ``axis='y'`` when the fringes
    code projector rows. Per-pixel coefficients are computed lazily once (float64 -> float32) and
    kept; :meth:`cached` returns a shared instance for a repeated geometry.

    ``pixels`` ((H, W, 2) float64, optional): a camera with lens distortion. Pixel (u, v) then sees
    the ray of the ideal pixel ``pixels[v, u]`` (its undistorted coordinates under the same K,
    `datapipe.lens.RenderGrid.ideal_pixels`), as a real scanner undistorts before it triangulates;
    every quantity that is linear in (u, v) is then kept per pixel (5 float32 maps more). Without
    it (None) every result is bit for bit that of a distortion-free camera.
    """

    _cache: "OrderedDict[bytes, Triangulator]" = OrderedDict()
    _cache_size = 4

    def __init__(self, P_cam, P_proj, cam_size, proj_size, *, axis: str = "x", pixels=None):
        P_cam = _finite_matrix(P_cam, (3, 4), "P_cam")
        P_proj = _finite_matrix(P_proj, (3, 4), "P_proj")
        self.cam_size = _size(cam_size, "cam_size")
        self.proj_size = _size(proj_size, "proj_size")
        if axis not in ("x", "y"):
            raise bad_value("axis", f"must be 'x' or 'y', got {axis!r}", "'x' when fringes code projector columns")
        self.axis = axis
        Pc = _normalise_camera(P_cam, "P_cam")
        Pp = _normalise_camera(P_proj, "P_proj")
        if axis == "y":
            Pp = Pp[[1, 0, 2]]
        self.P_cam, self.P_proj = Pc, Pp
        M, p4 = Pc[:, :3], Pc[:, 3]
        Kc, _ = scipy.linalg.rq(M)
        Kc = Kc @ np.diag(np.sign(np.diag(Kc)))
        self.K_cam = Kc / Kc[2, 2]
        H = Pp[:, :3] @ np.linalg.inv(M)
        self._H = H
        self._beta = Pp[:, 3] - H @ p4
        self._coef = None
        self._pixels = None
        if pixels is not None:
            px = np.asarray(pixels, dtype=np.float64)
            w, h = self.cam_size
            if px.shape != (h, w, 2) or not np.all(np.isfinite(px)):
                raise bad_value("pixels", f"has shape {px.shape} (or non-finite values), expected {(h, w, 2)}",
                                "pass the ideal (undistorted) pixel coordinates of every camera pixel")
            self._pixels = px

    # -- construction helpers --------------------------------------------------------------
    @classmethod
    def cached(cls, P_cam, P_proj, cam_size, proj_size, *, axis: str = "x", pixels=None) -> "Triangulator":
        """A shared instance for this geometry (LRU of the last few), coefficients kept."""
        parts = [np.ascontiguousarray(P_cam, dtype=np.float64).tobytes(),
                 np.ascontiguousarray(P_proj, dtype=np.float64).tobytes(),
                 repr((tuple(int(v) for v in cam_size), tuple(int(v) for v in proj_size), axis)).encode()]
        if pixels is not None:
            import hashlib
            parts.append(hashlib.sha1(np.ascontiguousarray(pixels, dtype=np.float64).tobytes()).digest())
        key = b"".join(parts)
        tri = cls._cache.get(key)
        if tri is None:
            tri = cls(P_cam, P_proj, cam_size, proj_size, axis=axis, pixels=pixels)
            cls._cache[key] = tri
            while len(cls._cache) > cls._cache_size:
                cls._cache.popitem(last=False)
        else:
            cls._cache.move_to_end(key)
        return tri

    @classmethod
    def clear_cache(cls):
        cls._cache.clear()

    @property
    def coefficients(self) -> dict:
        """Per-pixel float32 array ``xinf`` (computed in float64 once, then kept; 4 bytes per pixel):

        the projector coordinate of the pixel's ray at infinite depth, ``a0/a2``, so that
        ``Z = (b0 - b2 x) / (x - xinf) / a2``. Forming the disparity
        ``x - xinf`` by one float32 subtraction avoids the cancellation of ``a2 x - a0``: float32
        evaluation adds about one ulp of x (the rounding of xinf plus that of the subtraction)
        times ``|dZ/dx|``, plus a few ulps of Z. Rays parallel to the projector's image plane
        (``a2 = 0``, far outside practical fields of view) get ``xinf = inf`` and are flagged.

        Quantities that are linear in the pixel coordinates (``a1``, ``a2``, ``q = b0 a2 - b2 a0``
        and the rays ``K^-1 (u, v, 1)``) are kept as a row vector plus a column vector
        (``lin``) and summed per slab.
        """
        if self._coef is None:
            self._coef = self._compute_coefficients()
        return self._coef

    def _linear_rows(self):
        """3-vectors (coefficients of u, v, 1) of the quantities linear in the pixel coordinates."""
        H, b = self._H, self._beta
        Kinv = np.linalg.inv(self.K_cam)
        return {"a1": H[1], "a2": H[2], "q": b[0] * H[2] - b[2] * H[0], "rx": Kinv[0], "ry": Kinv[1]}

    def _compute_coefficients(self):
        if self._pixels is not None:
            return self._compute_pixel_coefficients()
        w, h = self.cam_size
        u = np.arange(w, dtype=np.float64)
        H = self._H
        out = {"xinf": np.empty((h, w), np.float32)}
        step = max(1, (1 << 16) // w)
        with np.errstate(all="ignore"):
            for r0 in range(0, h, step):
                r1 = min(h, r0 + step)
                v = np.arange(r0, r1, dtype=np.float64)[:, None]
                a0, a2 = (H[i, 0] * u + H[i, 1] * v + H[i, 2] for i in (0, 2))
                out["xinf"][r0:r1] = np.where(a2 != 0, a0 / a2, np.inf)
        lin = {}
        vv = np.arange(h, dtype=np.float64)
        for k, c in self._linear_rows().items():
            lin[k] = ((c[0] * u)[None, :].astype(np.float32), (c[1] * vv + c[2])[:, None].astype(np.float32))
        out["lin"] = lin
        return out

    def _compute_pixel_coefficients(self):
        """With `pixels`: the same quantities, evaluated at each pixel's ideal coordinates (per pixel)."""
        u, v = self._pixels[..., 0], self._pixels[..., 1]
        H = self._H
        with np.errstate(all="ignore"):
            a0, a2 = (H[i, 0] * u + H[i, 1] * v + H[i, 2] for i in (0, 2))
            xinf = np.where(a2 != 0, a0 / a2, np.inf).astype(np.float32)
        lin = {k: ((c[0] * u + c[1] * v + c[2]).astype(np.float32), None) for k, c in self._linear_rows().items()}
        return {"xinf": xinf, "lin": lin}

    def _lin(self, name, r0, r1, out=None):
        row, col = self.coefficients["lin"][name]
        if col is None:                                   # per pixel (a distorting lens)
            if out is None:
                return row[r0:r1].copy()
            np.copyto(out, row[r0:r1])
            return out
        return np.add(row, col[r0:r1], out=out)

    # -- evaluation ------------------------------------------------------------------------
    def slab(self, x, r0, r1, *, max_depth_slope=None, check_other_axis=True, out_depth=None):
        """Evaluate rows ``r0:r1`` for projector coordinates ``x`` (float32 (r1-r0, W)).

        Returns ``(depth, ill, outside)``: depth float32 (not NaN-filled), bool masks.
        """
        return self._evaluate(x, self.coefficients["xinf"][r0:r1], lambda name, out=None: self._lin(name, r0, r1, out),
                              max_depth_slope, check_other_axis, out_depth)

    def at(self, x, flat, *, max_depth_slope=None, check_other_axis=True):
        """:meth:`slab` at the pixels ``flat`` (flat indices) only, for their coordinates ``x`` (1D
        float32): the same float32 operations on each pixel, so the same values, without
        evaluating the rest of their rows."""
        W = self.cam_size[0]
        r, c = np.divmod(np.asarray(flat), W)
        co = self.coefficients

        def lin(name, out=None):
            row, col = co["lin"][name]
            v = row[r, c] if col is None else np.add(row[0, c], col[r, 0])
            if out is None:
                return v
            np.copyto(out, v)
            return out

        return self._evaluate(x, co["xinf"][r, c], lin, max_depth_slope, check_other_axis, None)

    def _evaluate(self, x, xinf, lin, max_depth_slope, check_other_axis, out_depth):
        """Depth, ill-conditioned and outside masks from coordinates x, the disparity origin xinf
        and ``lin(name, out=None)``, the linear coefficient maps at the same pixels."""
        b0, b1, b2 = (np.float32(v) for v in self._beta)
        f32 = np.float32
        num = np.multiply(x, -b2)
        num += b0
        d = np.subtract(x, xinf)                          # disparity w.r.t. infinity
        num /= d                                          # inf/nan where d == 0: flagged below
        a2 = lin("a2")
        z = np.divide(num, a2, out=out_depth)
        zp = np.multiply(a2, z, out=a2)
        zp += b2                                          # depth in the projector frame
        # ill-conditioned: |dZ/dx| = Zp^2/|q| > cap  <=>  not (Zp^2 <= cap*|q|); NaN -> ill
        lhs = np.multiply(zp, zp, out=num)
        rhs = lin("q")
        np.abs(rhs, out=rhs)
        if max_depth_slope is None:              # default: relative cap |dZ/dx| <= Z per pixel
            rhs *= z
        else:
            rhs *= f32(max_depth_slope)
        ok = lhs <= rhs
        ok &= z > 0
        ok &= np.isfinite(z)
        outside = ~(zp > 0)
        if check_other_axis:
            y = lin("a1", out=lhs)
            y *= z
            y += b1
            y /= zp
            hp = f32(self.proj_size[1] if self.axis == "x" else self.proj_size[0])
            inside = (y >= f32(-0.5)) & (y <= hp - f32(0.5))
            outside |= ~inside
        return z, ~ok, outside

    def points_into(self, depth, r0, r1, out):
        """Camera-frame points ``Z * K^-1 (u, v, 1)`` for rows r0:r1 into ``out`` (.., 3)."""
        np.multiply(depth, self._lin("rx", r0, r1), out=out[..., 0])
        np.multiply(depth, self._lin("ry", r0, r1), out=out[..., 1])
        out[..., 2] = depth
        return out

    def points(self, depth) -> np.ndarray:
        """(H, W, 3) float32 camera-frame points of a depth map (NaN depth -> NaN points)."""
        depth = np.asarray(depth, dtype=np.float32)
        h = depth.shape[0]
        out = np.empty(depth.shape + (3,), np.float32)
        step = max(1, (1 << 16) // depth.shape[1])
        for r0 in range(0, h, step):
            r1 = min(h, r0 + step)
            self.points_into(depth[r0:r1], r0, r1, out[r0:r1])
        return out

    def __call__(self, proj_x, *, max_depth_slope=None, check_other_axis=True) -> TriangulationResult:
        """Depth and camera-frame points for a full ``(H, W)`` map of projector coordinates."""
        w, h = self.cam_size
        x = np.asarray(proj_x, dtype=np.float32)
        if x.shape != (h, w):
            raise bad_value("proj_x", f"has shape {x.shape}, expected {(h, w)} (cam_size is {(w, h)})",
                            "pass one projector coordinate per camera pixel")
        depth = np.empty((h, w), np.float32)
        pts = np.empty((h, w, 3), np.float32)
        with np.errstate(all="ignore"):
            z, ill, out = self.slab(x, 0, h, max_depth_slope=max_depth_slope,
                                    check_other_axis=check_other_axis, out_depth=depth)
            bad = ill | out | ~np.isfinite(x)
        depth[bad] = np.nan
        self.points_into(depth, 0, h, pts)
        return TriangulationResult(depth=depth, points=pts, ill_conditioned=ill, outside=out)

    def depth_slope(self, depth) -> np.ndarray:
        """``|dZ/dx|`` (metres per projector pixel) at the given depth map: the depth uncertainty
        per pixel of projector-coordinate error (multiply by sigma_x). inf where ill-conditioned."""
        w, h = self.cam_size
        z = np.asarray(depth, dtype=np.float64)
        u = np.arange(w, dtype=np.float64)[None, :]
        v = np.arange(h, dtype=np.float64)[:, None]
        if self._pixels is not None:
            u, v = self._pixels[..., 0], self._pixels[..., 1]
        lr = self._linear_rows()
        a2 = lr["a2"][0] * u + lr["a2"][1] * v + lr["a2"][2]
        q = lr["q"][0] * u + lr["q"][1] * v + lr["q"][2]
        zp = z * a2 + self._beta[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return (zp * zp / np.abs(q)).astype(np.float32)

    def project(self, points_cam) -> np.ndarray:
        """Projector pixel coordinates ``(..., 2)`` of camera-frame points (float64), for checks."""
        X = np.asarray(points_cam, dtype=np.float64)
        m = X @ self.K_cam.T          # = Z (u, v, 1)
        p = m @ self._H.T + self._beta
        xy = p[..., :2] / p[..., 2:3]
        return xy[..., ::-1] if self.axis == "y" else xy
