"""Checks that need Blender, run before the output folder is touched.

`measure_meshes(cfg)` imports every distinct mesh file once, measures it and removes everything the
import added, so every entry through the gate (datapipe/engine/gate.py: `datapipe validate` and
`run`, the add-on, the Ray driver) refuses the same broken part files (no faces, NaN vertices, a
part bigger than the bin or too small to see) before anything is written; the hull volumes it
measures feed the gate's part-fit step (part_fit.fill_problems); `check_meshes` is both at once.
`check_blend(cfg)` reads `scene.blend_file` with Blender's own reader without opening it (the open
scene stays).
"""
from __future__ import annotations

import os

import bpy
import numpy as np

from ..config import Config
from ..config.plan import camera_distances
from ..errors import Problem
from ..io.bop_models import entry_field
from ..draws.fill import hull_volume
from ..checks.part_fit import fill_problems
from ..geometry import camera_intrinsics
from .. import collision, shapes
from .objects import _IMPORTERS, DECOMPOSED_SHAPES, _run_importer, remove_import_leftovers

MIN_PART_PX = 0.25       # a part narrower than this on the camera image is not in the dataset (tiny
                         # test renders go down to ~1 px parts; a wrong scale is orders of magnitude off)


def _import_measure(path: str) -> tuple[int, int, np.ndarray, np.ndarray]:
    """(vertex count, face count, (V, 3) world vertices, (T, 3) triangles into them) of every mesh in
    the file; leaves no data."""
    before_objs, before_meshes = set(bpy.data.objects), set(bpy.data.meshes)
    before_colls = set(bpy.data.collections)
    try:
        _run_importer(_IMPORTERS[os.path.splitext(path)[1].lower()], path)
        new = [o for o in bpy.data.objects if o not in before_objs]
        pts, tris, n_faces, n_verts = [], [], 0, 0
        for o in new:
            if o.type == "MESH" and o.data is not None:
                me = o.data
                v = np.empty(len(me.vertices) * 3, np.float64)
                me.vertices.foreach_get("co", v)
                mw = np.array(o.matrix_world, dtype=np.float64)
                pts.append(v.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3])
                n_faces += len(me.polygons)
                me.calc_loop_triangles()
                t = np.empty(len(me.loop_triangles) * 3, np.int32)
                me.loop_triangles.foreach_get("vertices", t)
                tris.append(t.reshape(-1, 3).astype(np.int64) + n_verts)
                n_verts += len(me.vertices)
        allpts = np.concatenate(pts) if pts else np.zeros((0, 3))
        alltris = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
        return len(allpts), n_faces, allpts, alltris
    finally:
        remove_import_leftovers(before_objs, before_meshes, before_colls)


def check_meshes(cfg: Config) -> list[Problem]:
    """Problems of the part files themselves and of the bin's fill (call after Config.validate() passed)."""
    problems, volumes = measure_meshes(cfg)
    if not problems and cfg.scene.blend_file is None:       # a .blend's drop_zone is known only once open
        problems += fill_problems(cfg, volumes)
    return problems


def measure_meshes(cfg: Config, boxes: dict[int, tuple] | None = None) -> tuple[list[Problem], dict[int, float]]:
    """(problems of the part files, {object entry: one part's convex-hull volume in m^3}); the volumes
    only without scene.blend_file (they are for part_fit.fill_problems against the configured bin).
    `boxes`, when given, gets {object entry: (lo, hi)}: its mesh's bounding box in file units
    (checks/origins.py)."""
    problems: list[Problem] = []
    measured: dict[str, tuple] = {}
    hulls: dict[str, float] = {}
    volumes: dict[int, float] = {}          # entry -> one part's hull volume, m^3
    zone = np.asarray(cfg.scene.drop_zone_scale, dtype=np.float64) * 2        # full extents, m
    c = cfg.camera
    fx = float(camera_intrinsics(c)[0, 0])          # camera.intrinsics when given (a calibration)
    far = max(camera_distances(cfg))
    for i, o in enumerate(cfg.objects):
        field = f"{entry_field(o, i)}.filepath"
        path = os.path.abspath(o.filepath)
        if o.shape is not None:           # a procedural distractor: measured at its largest size
            path = f"shape:{i}"
            v, f = shapes.mesh(o.shape["kind"], shapes.largest(o.shape, 1.0))
            measured[path] = (len(v), len(f), v, f)
        if path not in measured:
            try:
                measured[path] = _import_measure(path)
            except RuntimeError as e:
                measured[path] = str(e).strip().splitlines()[-1] if str(e).strip() else "importer failed"
        m = measured[path]
        if isinstance(m, str):
            problems.append(Problem(field, f"cannot import {path}: {m}", "check that the file is a valid mesh "
                                    "file of that format"))
            continue
        n_verts, n_faces, pts, tris = m
        if n_verts == 0 or n_faces == 0:
            problems.append(Problem(field, f"{path} holds {n_verts} vertices and {n_faces} faces: nothing to "
                                    "render or simulate", "export the part as a polygon mesh (OBJ: 'v' and 'f' "
                                    "lines)"))
            continue
        if not np.isfinite(pts).all():
            problems.append(Problem(field, f"{path} has NaN or infinite vertex coordinates",
                                    "repair the mesh in a modeller and export it again"))
            continue
        if o.shape is None and not collision.coacd_available() and _needs_pieces(o.collision_shape, pts, tris):
            problems.append(collision.missing_coacd(f"{entry_field(o, i)}.collision_shape"))
        if boxes is not None:
            boxes[i] = (pts.min(axis=0), pts.max(axis=0))
        with np.errstate(over="ignore"):       # a scale of 1e308: reported below, not warned about
            size = (pts.max(axis=0) - pts.min(axis=0)) * o.scale
        longest = float(size.max())
        if cfg.scene.blend_file is None and longest > float(np.linalg.norm(zone)):
            problems.append(Problem(f"{entry_field(o, i)}.scale", f"the part is {longest:.3g} m long at scale {o.scale:g}, "
                                    f"longer than the drop zone's diagonal ({np.linalg.norm(zone):.3g} m)",
                                    "check the scale (file units -> metres: mm files need 0.001) or enlarge "
                                    "scene.drop_zone_scale"))
        elif not longest <= c.clip_end:          # with a .blend too (its zone is unknown here); inf, NaN
            problems.append(Problem(f"{entry_field(o, i)}.scale", f"the part is {longest:.3g} m long at scale {o.scale:g}, "
                                    f"longer than the camera sees (camera.clip_end {c.clip_end:g} m)",
                                    "check the scale (file units -> metres: mm files need 0.001)"))
        elif longest * fx / far < MIN_PART_PX:
            problems.append(Problem(f"{entry_field(o, i)}.scale", f"the part is {longest:.3g} m long at scale {o.scale:g}: "
                                    f"{longest * fx / far:.2g} px on the camera image from {far:.2f} m",
                                    "check the scale (file units -> metres), or move the camera closer"))
        elif cfg.scene.blend_file is None:      # a sane size: the scale cubed stays finite (1e308 would not)
            if path not in hulls:
                hulls[path] = hull_volume(pts)
            volumes[i] = hulls[path] * o.scale ** 3
    return problems, volumes


def check_blend(cfg: Config) -> list[Problem]:
    """scene.blend_file read by Blender (its header, DNA and block list), without opening it: a file
    Blender cannot load fails here instead of after the run wrote its first files. The objects of
    that file (or, without one, of the scene open in Blender) must not already carry the name of an
    instance (`{entry name}_{k:03d}`): the run would stop at the first scene that makes it."""
    path = cfg.scene.blend_file
    if not path:
        return _name_clashes(cfg, [o.name for o in bpy.data.objects], "the scene open in Blender")
    before = set(bpy.data.libraries)
    try:
        with bpy.data.libraries.load(path) as (src, _dst):
            names = list(src.objects)
    except (OSError, RuntimeError) as e:
        why = str(e).strip().splitlines()[-1].removeprefix("Error: ") if str(e).strip() else type(e).__name__
        return [Problem("scene.blend_file", f"Blender cannot read {path}: {why}", "give a .blend saved by "
                        "Blender: re-save it from Blender, or restore it from a backup")]
    finally:
        for lib in set(bpy.data.libraries) - before:     # reading links nothing; be sure nothing stays
            bpy.data.libraries.remove(lib)
    return _name_clashes(cfg, names, path)


def _name_clashes(cfg: Config, names: list[str], where: str) -> list[Problem]:
    taken, problems = set(names), []
    for i, o in enumerate(cfg.objects):
        name = cfg.object_name(i)
        hit = next((f"{name}_{k:03d}" for k in range(o.max_instances) if f"{name}_{k:03d}" in taken), None)
        if hit is not None:
            problems.append(Problem(f"{entry_field(cfg.objects[i], i)}.name", f"{where} already has an object named {hit!r}, the "
                                    "name one of this entry's instances gets", "give the entry another name, or "
                                    f"rename {hit!r} in the .blend"))
    return problems


def _needs_pieces(shape: str, pts: np.ndarray, tris: np.ndarray) -> bool:
    """Whether the part is simulated as convex pieces (objects.py resolves AUTO the same way)."""
    return shape in DECOMPOSED_SHAPES or (shape == "AUTO" and collision.is_clearly_concave(pts, tris))
