"""A synthetic native-output generator (docs/ARCHITECTURE.md layout) from ANALYTIC geometry, no Blender.

Boxes (cuboid models, faces subdivided into a grid so that vertices also lie inside faces) rest on
a floor plane z = 0; per render every pixel centre is ray-cast in numpy, which gives the exact
planar depth (depth.exr), the instance mask (mask.exr, pass index), camera-frame normals
(normals.exr), a shaded rgb.png, and optionally a structured-light-like depth (sl_depth.exr =
depth + noise with NaN holes at edges and at random) with sl_valid.png. scene.json, run.json,
output_dict.pickle and models/ (via write_models) are written like the pipeline writes them, scene
by scene, scene.json last.

Scenes are deterministic from (seed, scene index) (datapipe.draws.seeds), and the plan comes from
datapipe.draws.seeds.plan_scenes, so a shard of a run holds the very scenes one process makes.

Also a stand-in for the headless runner (used by the Ray tests until the real pipeline exists):

    python tests/fixtures_native.py run PRESET.json --out DIR [--shard i/n] [--seed S] [--resume]

FIXTURE_SCENE_DELAY=<seconds> sleeps after each scene (so a test can kill it mid-way).
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from datapipe.config import Config, ObjectEntry, CameraPose
from datapipe.io.legacy import LegacyPickleWriter
from datapipe.io.exr import write_exr
from datapipe.geometry import BLENDER_TO_OPENCV, intrinsics_from_sensor
from datapipe.draws.seeds import plan_scenes, render_seed, scene_seed, shard_scenes, parse_shard

# half extents (m) of the box models, obj_id = index + 1
BOX_HALF = [(0.020, 0.015, 0.010), (0.030, 0.010, 0.0075), (0.0125, 0.0125, 0.0125)]


def box_mesh(half, n: int = 4):
    """Cuboid centred at the origin, each face an n x n grid of quads (2 triangles each).

    Returns (verts (V,3) m, faces (F,3), normals (V,3)); vertices are per face (flat normals)."""
    hx, hy, hz = half
    verts, faces, normals = [], [], []
    g = np.linspace(-1.0, 1.0, n + 1)
    a, b = np.meshgrid(g, g, indexing="ij")
    a, b = a.ravel(), b.ravel()
    for axis in range(3):
        for s in (-1.0, 1.0):
            u_ax, v_ax = [k for k in range(3) if k != axis]
            if s < 0:
                u_ax, v_ax = v_ax, u_ax            # keep the winding outward-facing
            p = np.zeros((len(a), 3))
            p[:, axis] = s
            p[:, u_ax] = a
            p[:, v_ax] = b
            p *= np.array(half)
            base = sum(len(v) for v in verts)
            verts.append(p)
            nrm = np.zeros(3)
            nrm[axis] = s
            normals.append(np.tile(nrm, (len(p), 1)))
            for i in range(n):
                for j in range(n):
                    q00 = base + i * (n + 1) + j
                    q10 = q00 + (n + 1)
                    faces.append([q00, q10, q10 + 1])
                    faces.append([q00, q10 + 1, q00 + 1])
    return np.vstack(verts), np.array(faces, dtype=np.int64), np.vstack(normals)


def box_meshes(n: int = 4) -> dict:
    return {i + 1: box_mesh(h, n) for i, h in enumerate(BOX_HALF)}


def look_at(position, target) -> np.ndarray:
    """T_world_cam (OpenCV frame) of a camera at `position` looking at `target` (world +Y ~ image up)."""
    p, q = np.asarray(position, float), np.asarray(target, float)
    z = (q - p) / np.linalg.norm(q - p)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = p
    return T


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rot_axis(axis, a):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


DEFAULT_POSES = [((0.0, 0.0, 0.55), (0.0, 0.0, 0.0)), ((0.08, 0.0, 0.52), (0.01, 0.0, 0.0)),
                 ((-0.06, 0.05, 0.5), (0.0, 0.01, 0.0)), ((0.0, -0.08, 0.53), (0.0, 0.0, 0.0)),
                 ((0.05, 0.06, 0.6), (0.0, 0.0, 0.0))]


def scene_objects(seed: int, scene: int, *, min_boxes=2, max_boxes=3, spread=0.09, truncate=False):
    """[(obj_id, T_world_obj)] for scene `scene`, deterministic from (seed, scene)."""
    rng = np.random.default_rng(scene_seed(seed, scene))
    n = int(rng.integers(min_boxes, max_boxes + 1))
    objs = []
    tops = []
    for k in range(n):
        obj_id = int(rng.integers(1, len(BOX_HALF) + 1))
        half = np.array(BOX_HALF[obj_id - 1])
        R = rot_z(rng.uniform(-np.pi, np.pi))
        if rng.uniform() < 0.4:                                    # tilted part
            R = rot_axis([rng.uniform(-1, 1), rng.uniform(-1, 1), 0.0], rng.uniform(0.1, 0.4)) @ R
        xy = rng.uniform(-spread, spread, 2)
        if truncate and k == 0:
            xy = np.array([0.19, 0.0])                          # across the right image border
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        z = -(corners @ R.T)[:, 2].min()
        if tops and rng.uniform() < 0.35:                         # stack on an earlier part
            j = int(rng.integers(len(tops)))
            xy = tops[j][0] + rng.uniform(-0.01, 0.01, 2)
            z += tops[j][1]
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [xy[0], xy[1], z]
        objs.append((obj_id, T))
        tops.append((xy, z + (np.abs(corners @ R.T)[:, 2]).max()))
    return objs


def raycast(K, T_world_cam, objs, W, H):
    """Exact z-buffer of boxes (objs: [(obj_id, T_world_obj)]) on the floor z = 0.

    Returns depth (H,W) m (NaN = no hit), index (H,W) int (0 floor, k+1 box k), normals_world (H,W,3)."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    Kinv = np.linalg.inv(K)
    d_c = np.stack([u, v, np.ones_like(u)], -1) @ Kinv.T          # z = 1: ray parameter = planar depth
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d_w = d_c @ R.T
    depth = np.full((H, W), np.nan)
    index = np.zeros((H, W), np.int32)
    nrm = np.zeros((H, W, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = -o[2] / d_w[..., 2]
    hit = np.isfinite(t_floor) & (t_floor > 0)
    depth[hit] = t_floor[hit]
    nrm[hit] = [0, 0, 1.0]
    for k, (obj_id, T) in enumerate(objs):
        half = np.array(BOX_HALF[obj_id - 1])
        Ro, po = T[:3, :3], T[:3, 3]
        ob = (o - po) @ Ro                                        # = Ro^T (o - po)
        db = d_w @ Ro
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - ob) / db
            t2 = (half - ob) / db
        tmin = np.minimum(t1, t2)
        tmax = np.maximum(t1, t2)
        tmin = np.where(np.isnan(tmin), -np.inf, tmin)
        tmax = np.where(np.isnan(tmax), np.inf, tmax)
        t_near = tmin.max(-1)
        t_far = tmax.min(-1)
        ax = tmin.argmax(-1)
        ok = (t_near <= t_far) & (t_near > 0) & (np.isnan(depth) | (t_near < depth))
        if not ok.any():
            continue
        depth[ok] = t_near[ok]
        index[ok] = k + 1
        sgn = -np.sign(np.take_along_axis(db, ax[..., None], -1)[..., 0])
        nb = np.zeros((H, W, 3))
        np.put_along_axis(nb, ax[..., None], sgn[..., None], -1)
        nrm[ok] = nb[ok] @ Ro.T
    return depth, index, nrm


COLORS = np.array([[200, 80, 60], [60, 160, 220], [90, 200, 90], [220, 200, 60], [180, 90, 200],
                   [240, 140, 40], [60, 200, 190], [200, 200, 200]], dtype=np.float64)


def shade(index, nrm_world, u_grid=None):
    H, W = index.shape
    light = np.array([0.3, -0.4, 0.87])
    light /= np.linalg.norm(light)
    lam = np.clip(nrm_world @ light, 0, 1)
    base = np.where(index[..., None] > 0, COLORS[(index - 1) % len(COLORS)], 120.0)
    img = base * (0.35 + 0.65 * lam[..., None])
    return np.clip(img, 0, 255).astype(np.uint8)


def _atomic_write_bytes(path: Path, data: bytes):
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_box_objs(mesh_dir) -> list[Path]:
    """The box models as OBJ files (metres), so that a Config pointing at them validates."""
    mesh_dir = Path(mesh_dir)
    mesh_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for obj_id, (v, f, _) in box_meshes(1).items():
        p = mesh_dir / f"box{obj_id}.obj"
        p.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v)
                     + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
        paths.append(p)
    return paths


def default_config(*, num_renders=4, min_per_scene=2, max_per_scene=2, seed=0, resolution=(320, 240),
                   structured_light=False, formats=("native",), mesh_dir=None) -> Config:
    """A Config for the synthetic runs; with mesh_dir, its object entries point at real OBJ files."""
    cfg = Config()
    cfg.scene.num_renders = num_renders
    cfg.scene.min_renders_per_scene = min_per_scene
    cfg.scene.max_renders_per_scene = max_per_scene
    cfg.scene.seed = seed
    paths = write_box_objs(mesh_dir) if mesh_dir else [f"/synthetic/box{i + 1}.obj" for i in range(len(BOX_HALF))]
    cfg.objects = [ObjectEntry(filepath=str(paths[i]), name=f"box{i + 1}", min_instances=0,
                               max_instances=3) for i in range(len(BOX_HALF))]
    cfg.camera.resolution = list(resolution)
    cfg.camera.poses = [CameraPose(location=list(p), rotation=[1.0, 0, 0, 0]) for p, _ in DEFAULT_POSES]
    cfg.structured_light.enabled = structured_light
    cfg.output.formats = list(formats)
    return cfg


def write_scene(out: Path, cfg: Config, seed: int, scene: int, plan: list[int], *, min_boxes=2, max_boxes=3,
                spread=0.09, truncate=False, sl_noise_mm=0.3, sl_hole_fraction=0.03):
    W, H = cfg.camera.resolution
    K = intrinsics_from_sensor(cfg.camera.focal_length, cfg.camera.sensor_width, W, H)
    objs = scene_objects(seed, scene, min_boxes=min_boxes, max_boxes=max_boxes, spread=spread, truncate=truncate)
    name = f"scene.{scene + 1:04d}"
    sdir = out / name
    sdir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(scene_seed(seed, scene) + 1)
    pose_idx = rng.permutation(len(DEFAULT_POSES))[:plan[scene]]
    first_image = int(sum(plan[:scene]))
    names = {}
    objects_entries = []
    counts = {}
    for k, (obj_id, _) in enumerate(objs):
        counts[obj_id] = counts.get(obj_id, -1) + 1
        nm = f"box{obj_id}_{counts[obj_id]:03d}"
        names[k] = nm
        objects_entries.append({"name": nm, "filename": f"/synthetic/box{obj_id}.obj", "obj_id": obj_id,
                                "mask_index": k + 1})
    renders = []
    for r in range(plan[scene]):
        rname = f"render.{r + 1:04d}"
        rdir = sdir / rname
        rdir.mkdir(exist_ok=True)
        pos, tgt = DEFAULT_POSES[int(pose_idx[r])]
        T_wc = look_at(pos, tgt)
        depth, index, nrm = raycast(K, T_wc, objs, W, H)
        rs = render_seed(seed, scene, r)
        cv2.imwrite(str(rdir / "rgb.png"), shade(index, nrm)[..., ::-1])
        write_exr(rdir / "depth.exr", {"Z": depth.astype(np.float32)})
        nc = nrm @ T_wc[:3, :3]                                 # world -> camera: R_wc^T n
        write_exr(rdir / "normals.exr", {"X": nc[..., 0], "Y": nc[..., 1], "Z": nc[..., 2]})
        write_exr(rdir / "mask.exr", {"Y": index.astype(np.float32)})
        files = {"rgb": f"{rname}/rgb.png", "depth": f"{rname}/depth.exr", "normals": f"{rname}/normals.exr",
                 "mask": f"{rname}/mask.exr"}
        rd = {"render_id": r, "name": rname, "image_id": first_image + r, "pose_index": int(pose_idx[r]),
              "K": K.tolist(), "resolution": [W, H], "T_world_cam": T_wc.tolist(),
              "T_world_blcam": (T_wc @ BLENDER_TO_OPENCV).tolist(), "seed": rs, "files": files,
              "objects": []}
        if cfg.structured_light.enabled:
            nrng = np.random.default_rng(rs)
            sl = depth + nrng.normal(0, sl_noise_mm / 1000.0, depth.shape)
            gy, gx = np.gradient(np.nan_to_num(depth))
            holes = (np.hypot(gx, gy) > 0.002) | (nrng.uniform(size=depth.shape) < sl_hole_fraction)
            holes = cv2.dilate(holes.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            sl[holes] = np.nan
            write_exr(rdir / "sl_depth.exr", {"Z": sl.astype(np.float32)})
            cv2.imwrite(str(rdir / "sl_valid.png"), np.isfinite(sl).astype(np.uint8) * 255)
            files["sl_depth"] = f"{rname}/sl_depth.exr"
            files["sl_valid"] = f"{rname}/sl_valid.png"
            rd["structured_light"] = {"valid_fraction": float(np.isfinite(sl).mean())}
        T_cw = np.linalg.inv(T_wc)
        for k, (obj_id, T_wo) in enumerate(objs):
            T_co = T_cw @ T_wo
            cam2obj = BLENDER_TO_OPENCV @ T_co
            rd["objects"].append({"name": names[k], "filename": f"/synthetic/box{obj_id}.obj", "obj_id": obj_id,
                                  "mask_index": k + 1, "T_cam_obj": T_co.tolist(), "cam2obj_pose": cam2obj.tolist(),
                                  "px_count_visib": int((index == k + 1).sum())})
        renders.append(rd)
    scene_json = {"scene_id": scene, "name": name, "seed": scene_seed(seed, scene),
                  "simulation": {"frames": 0, "settled": True, "removed": []},
                  "objects": objects_entries, "renders": renders, "complete": True}
    _atomic_write_bytes(sdir / "scene.json", (json.dumps(scene_json, indent=1) + "\n").encode())
    return name, scene_json, objs


def config_identity(cfg: Config) -> dict:
    d = cfg.to_dict()
    d["output"] = {k: v for k, v in d["output"].items() if k != "path"}
    return d


def _write_run_files(out: Path, cfg: Config, seed: int, plan, shard, done, legacy, status="running"):
    shard = tuple(shard) if shard else (0, 1)
    cfg = cfg.copy()
    cfg.scene.seed = seed
    cfg.output.path = str(Path(out).resolve())
    run = {"datapipe_version": "0.1.0", "config": cfg.to_dict(), "config_identity": config_identity(cfg),
           "seed": seed, "plan": plan, "shard": list(shard),
           "scenes": [f"scene.{i + 1:04d}" for i in shard_scenes(len(plan), shard)],
           "status": status, "scenes_done": sorted(f"scene.{i + 1:04d}" for i in done)}
    _atomic_write_bytes(out / "run.json", (json.dumps(run, indent=1) + "\n").encode())


def make_native_run(tmp_dir, *, cfg: Config | None = None, seed: int | None = None, shard=None, scenes=None,
                    min_boxes=2, max_boxes=3, spread=0.09, truncate=False, resume=False, scene_delay=0.0,
                    structured_light: bool | None = None, mesh_subdiv: int = 4) -> Path:
    """Write a synthetic native run into tmp_dir (created) and return its path.

    Defaults: 2 scenes x 2 renders of 2-3 boxes at 320x240, structured light off."""
    out = Path(tmp_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = cfg or default_config()
    if structured_light is not None:
        cfg.structured_light.enabled = structured_light
    seed = cfg.scene.seed if seed is None else seed
    plan = plan_scenes(cfg.scene.num_renders, cfg.scene.min_renders_per_scene, cfg.scene.max_renders_per_scene, seed)
    if scenes is None:
        scenes = shard_scenes(len(plan), shard) if shard else range(len(plan))
    from datapipe.io.models import write_models
    write_models(out / "models", box_meshes(mesh_subdiv))
    legacy = None
    done = [s for s in range(len(plan)) if (out / f"scene.{s + 1:04d}" / "scene.json").is_file()] if resume else []
    for s in scenes:
        if resume and s in done:
            continue
        name, scene_json, _ = write_scene(out, cfg, seed, s, plan, min_boxes=min_boxes, max_boxes=max_boxes,
                                          spread=spread, truncate=truncate)
        if cfg.output.legacy_pickle:
            LegacyPickleWriter(out).add_scene(out / name, scene_json)   # the pipeline's own writer (loads the file)
        done.append(s)
        _write_run_files(out, cfg, seed, plan, shard, done, legacy)
        if scene_delay:
            time.sleep(scene_delay)
    _write_run_files(out, cfg, seed, plan, shard, done, legacy, status="complete")
    return out


def main(argv=None) -> int:
    """Stand-in for `python -m datapipe run` (same arguments the Ray launcher passes)."""
    ap = argparse.ArgumentParser(prog="fixtures_native")
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("preset")
    r.add_argument("--out", required=True)
    r.add_argument("--shard", default=None)
    r.add_argument("--seed", type=int, default=None)
    r.add_argument("--resume", action="store_true")
    a = ap.parse_args(argv)
    from datapipe.config import load
    cfg = load(a.preset)
    shard = parse_shard(a.shard) if a.shard else None
    make_native_run(a.out, cfg=cfg, seed=a.seed, shard=shard, resume=a.resume,
                    scene_delay=float(os.environ.get("FIXTURE_SCENE_DELAY", "0")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
