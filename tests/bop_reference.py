"""Independent readers for a BOP export (no datapipe code): PLY, JSON with integer keys, PNG, and
the walk over every image's ground truth. Shared by tests/test_bop.py (synthetic runs) and
tests/blender/test_bop_real_run.py (a real Blender run)."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np


def ref_read_ply(path):
    """Vertices (V,3) of an ascii or binary_little_endian PLY; faces (F,3) for triangle meshes."""
    raw = Path(path).read_bytes()
    end = raw.index(b"end_header")
    body = raw.index(b"\n", end) + 1
    header = raw[:end].decode().splitlines()
    assert header[0] == "ply"
    fmt = next(l.split()[1] for l in header if l.startswith("format"))
    elems, cur = [], None
    for l in header:
        t = l.split()
        if t and t[0] == "element":
            cur = [t[1], int(t[2]), []]
            elems.append(cur)
        elif t and t[0] == "property":
            cur[2].append(t[1:])
    vert = elems[0]
    assert vert[0] == "vertex"
    names = [p[-1] for p in vert[2]]
    assert names[:6] == ["x", "y", "z", "nx", "ny", "nz"], names
    nv = vert[1]
    face = next(e for e in elems if e[0] == "face")
    if fmt == "ascii":
        lines = raw[body:].decode().split("\n")
        V = np.array([[float(x) for x in lines[i].split()] for i in range(nv)])
        F = np.array([[int(x) for x in lines[nv + i].split()] for i in range(face[1])])
        assert (F[:, 0] == 3).all()
        return V, F[:, 1:]
    assert fmt == "binary_little_endian"
    tmap = {"float": "<f4", "double": "<f8", "uchar": "u1", "int": "<i4", "uint": "<u4"}
    vdt = np.dtype([(p[-1], tmap[p[0]]) for p in vert[2]])
    V = np.frombuffer(raw, vdt, nv, body)
    pos = body + vdt.itemsize * nv
    lst = face[2][0]
    fdt = np.dtype([("n", tmap[lst[1]]), ("i", tmap[lst[2]], (3,))])
    F = np.frombuffer(raw, fdt, face[1], pos)
    assert (F["n"] == 3).all()
    return np.stack([V[n] for n in names], 1).astype(np.float64), F["i"].astype(np.int64)


def ref_load_json(path):
    with open(path) as f:
        data = json.load(f)
    return {int(k) if k.isdigit() else k: v for k, v in data.items()}


def ref_png(path, flags=cv2.IMREAD_UNCHANGED):
    im = cv2.imread(str(path), flags)
    assert im is not None, path
    return im


def iter_gt(bop_root, chunk_size=1000):
    """(image_id, chunk_dir, im_id, camera, [gt], [gt_info]) for every image of the export."""
    for cdir in sorted((bop_root / "train_pbr").iterdir()):
        cams = ref_load_json(cdir / "scene_camera.json")
        gts = ref_load_json(cdir / "scene_gt.json")
        infos = ref_load_json(cdir / "scene_gt_info.json")
        assert set(cams) == set(gts) == set(infos)
        for im_id in sorted(cams):
            yield int(cdir.name) * chunk_size + im_id, cdir, im_id, cams[im_id], gts[im_id], infos[im_id]
