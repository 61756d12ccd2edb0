"""The scanner's organised point cloud as a binary PLY (render output `point_cloud`). No bpy.

Real structured-light scanners deliver one point per camera pixel, in the camera's frame, with a
colour or grey value and a per-pixel quality (Zivid's SNR, PhoXi's confidence map). This file is
that, from the simulated scan (docs/DATASETS.md, "point_cloud.ply"):

    ply
    format binary_little_endian 1.0
    obj_info organised WIDTH HEIGHT (row-major, row 0 = top of the image)
    element vertex WIDTH*HEIGHT
    property float x                 metres, camera frame (OpenCV: x right, y down, z forward)
    property float y
    property float z
    property ushort grey (uchar for an 8-bit sensor)   the scanner's grey image (sl_gray), DN
    property float confidence        probability that the pixel's fringe orders are right, 0..1
    property float nx                unit normal facing the camera, from the organised neighbours
    property float ny
    property float nz
    end_header

Vertex i is pixel (u, v) = (i % WIDTH, i // WIDTH). A pixel without a valid depth has x = y = z =
NaN (and NaN normal, confidence 0): the organised layout keeps every pixel, as the vendors' own
organised clouds do. A valid pixel whose neighbours cannot give a normal has a NaN normal.

Points: the structured-light depth back-projected with the camera matrix K, pixel centres at
integer coordinates (BOP's and OpenCV's convention): x = (u - cx) z / fx, y = (v - cy) z / fy.
A camera with lens distortion (camera.distortion) back-projects along each pixel's undistorted ray
instead: x = x_n z, y = y_n z with (x_n, y_n) the pixel's ideal normalised coordinates (the same rays
the decoder triangulates with, datapipe/lens.py), so cv2.projectPoints with K and the distortion
maps every point back onto its pixel.
Normals: cross product of the central differences along the row and the column (one-sided at a
border or beside an invalid pixel), oriented towards the camera.

The header is written here (no PLY library needed); Open3D, trimesh and plyfile read the file as a
point cloud with these properties (an `obj_info` line is a comment to them).
"""
from __future__ import annotations

import os

import numpy as np

from .files import write_bytes_atomic


def back_project(depth_m: np.ndarray, K, rays=None) -> np.ndarray:
    """(H, W) planar depth (NaN / <= 0 = none) -> (H, W, 3) float64 camera-frame points, NaN where none.
    `rays`: (x_n, y_n), each (H, W), the pixels' ideal normalised coordinates of a distorting lens
    (None: the pinhole rays of K)."""
    z = np.asarray(depth_m, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    H, W = z.shape
    z = np.where(np.isfinite(z) & (z > 0), z, np.nan)
    if rays is None:
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        xn, yn = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    else:
        xn, yn = (np.asarray(r, dtype=np.float64) for r in rays)
        if xn.shape != (H, W) or yn.shape != (H, W):
            raise ValueError(f"rays of shape {xn.shape} for a {W}x{H} depth map")
    return np.stack([xn * z, yn * z, z], axis=-1)


def _diff(p: np.ndarray, axis: int) -> np.ndarray:
    """Central difference along `axis`, one-sided where a neighbour is missing (NaN) or at the border."""
    n = p.shape[axis]
    fwd = np.full_like(p, np.nan)
    bwd = np.full_like(p, np.nan)
    sl = lambda a, b: tuple(slice(a, b) if i == axis else slice(None) for i in range(p.ndim))  # noqa: E731
    fwd[sl(0, n - 1)] = p[sl(1, n)] - p[sl(0, n - 1)]
    bwd[sl(1, n)] = p[sl(1, n)] - p[sl(0, n - 1)]
    central = 0.5 * (fwd + bwd)
    return np.where(np.isnan(central), np.where(np.isnan(fwd), bwd, fwd), central)


def normals(points: np.ndarray) -> np.ndarray:
    """(H, W, 3) organised points (NaN = none) -> unit normals towards the camera, NaN where undefined."""
    du, dv = _diff(points, 1), _diff(points, 0)
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(norm > 0, n / norm, np.nan)
        flip = np.sum(n * points, axis=-1, keepdims=True) > 0       # facing away from the camera
    return np.where(flip, -n, n)


def vertex_dtype(grey_dtype) -> np.dtype:
    g = "<u1" if np.dtype(grey_dtype) == np.uint8 else "<u2"
    return np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("grey", g), ("confidence", "<f4"),
                     ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")])


def organised_cloud(depth_m: np.ndarray, K, grey: np.ndarray, confidence: np.ndarray | None,
                    rays=None) -> np.ndarray:
    """The structured vertex array (H*W,) of `vertex_dtype` (see the module doc; `rays`: back_project's)."""
    depth_m = np.asarray(depth_m)
    grey = np.asarray(grey)
    if grey.shape != depth_m.shape or grey.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"grey must be a uint8 or uint16 image of shape {depth_m.shape}, got {grey.dtype} {grey.shape}")
    pts = back_project(depth_m, K, rays)
    valid = np.isfinite(pts[..., 2])
    v = np.empty(depth_m.size, vertex_dtype(grey.dtype))
    for i, c in enumerate("xyz"):
        v[c] = pts[..., i].ravel()
    nrm = normals(pts)
    for i, c in enumerate(("nx", "ny", "nz")):
        v[c] = nrm[..., i].ravel()
    v["grey"] = grey.ravel()
    conf = np.zeros(depth_m.shape, np.float32) if confidence is None else np.asarray(confidence, np.float32)
    v["confidence"] = np.where(valid, np.nan_to_num(conf, nan=0.0), 0.0).ravel()
    return v


def ply_bytes(vertices: np.ndarray, width: int, height: int) -> bytes:
    """An organised binary little-endian PLY of `vertices` (a structured array of `vertex_dtype`)."""
    if vertices.shape != (width * height,):
        raise ValueError(f"{vertices.shape[0]} vertices for an organised {width}x{height} cloud")
    types = {"<f4": "float", "|u1": "uchar", "<u2": "ushort"}
    props = "".join(f"property {types[vertices.dtype[n].str]} {n}\n" for n in vertices.dtype.names)
    header = (f"ply\nformat binary_little_endian 1.0\ncomment DataPipe organised point cloud: metres, camera "
              f"frame (OpenCV), invalid pixels NaN\nobj_info organised {width} {height}\n"
              f"element vertex {width * height}\n{props}end_header\n")
    return header.encode("ascii") + vertices.astype(vertices.dtype.newbyteorder("<")).tobytes()


def write_point_cloud(path: str | os.PathLike, depth_m: np.ndarray, K, grey: np.ndarray,
                      confidence: np.ndarray | None = None, rays=None) -> None:
    """Write the organised point cloud of one scan (see the module doc), atomically."""
    H, W = np.asarray(depth_m).shape
    write_bytes_atomic(path, ply_bytes(organised_cloud(depth_m, K, grey, confidence, rays), W, H))
