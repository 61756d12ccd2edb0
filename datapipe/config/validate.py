"""validate(): every problem of a Config at once, each with its field path and the fix, before any
Blender work starts. The projector and structured-light rules are in validate_sl.py; rules that
belong to a domain live with it (materials_spec, devices, sl/, io/) and are called from here."""
from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import DataPipeError, Problem
from ..io.mesh_refs import mesh_ref_problems
from ..io.input_files import MAX_MESH_BYTES, file_problem, read_regular
from ..materials_spec import material_problem
from ..text_rules import name_problem, output_folder_problem, short as _short
from .checks import _Checks, _check_field_of_view, _finite, _is_number, _join, _range_problems, _split_field
from .limits import (ORIGINS, COLLISION_SHAPES, DENOISE_PREFILTERS, DENOISE_QUALITIES, DEVICES, ENGINES,
                     SAMPLING_PATTERNS, FORMATS, MAX_INSTANCES, MAX_INT32, MAX_RENDERS,
                     MAX_SAMPLES, MESH_SUFFIXES, OTHER_OBJECTS, OUTPUT_KINDS, PICK_ORDERS, SAMPLER_KINDS, SENSOR_FITS,
                     SL_OUTPUT_KINDS)
from .validate_looks import _check_environment, _check_textures
from .validate_sl import _check_projector, _check_structured_light

if TYPE_CHECKING:                 # annotations only: Config's methods call the rules, not the other way
    from .schema import Config, LightingConfig, ObjectEntry, SimulationConfig


def validate(cfg: Config, *, check_files: bool = True) -> list[Problem]:
    """Every problem at once, each with its field path and the fix. Empty list = valid.

    Runs the named steps of `VALIDATION_STEPS` in order. A field that holds NaN or infinity is
    reported once (by `_check_finite`); later steps do not repeat it with a second message."""
    ck = _Checks()
    _check_finite(ck, cfg, check_files)
    non_finite = {p.path for p in ck.problems}
    for step in VALIDATION_STEPS:
        step(ck, cfg, check_files)
    return [p for i, p in enumerate(ck.problems) if i < len(non_finite) or p.path not in non_finite]


def _check_finite(ck: _Checks, cfg: Config, check_files: bool) -> None:
    """No NaN or infinity anywhere: one problem per field (a list is reported at its own path)."""
    def walk(obj, path):
        if dataclasses.is_dataclass(obj):
            for f in dataclasses.fields(obj):
                walk(getattr(obj, f.name), _join(path, f.name))
        elif isinstance(obj, list):
            if any(_is_number(x) and not _finite(x) for x in obj):
                ck.add(path, "contains NaN or infinity", "give finite numbers")
            else:
                for i, x in enumerate(obj):
                    if dataclasses.is_dataclass(x):
                        walk(x, f"{path}[{i}]")
        elif isinstance(obj, float) and not math.isfinite(obj):
            ck.add(path, f"must be a finite number, got {obj!r}", "give a finite number")
    walk(cfg, "")


def _check_scene(ck: _Checks, cfg: Config, check_files: bool) -> None:
    s = cfg.scene
    ck.int_range("scene.num_renders", s.num_renders, 1, MAX_RENDERS, "renders")
    if ck.min_max("scene", "min_renders_per_scene", "max_renders_per_scene",
                  s.min_renders_per_scene, s.max_renders_per_scene, lo_bound=1):
        ck.at_most("scene.max_renders_per_scene", s.max_renders_per_scene, MAX_RENDERS,
                   "more renders per scene than the run may have")
    ck.vector("scene.drop_zone_loc", s.drop_zone_loc, 3)
    ck.vector("scene.drop_zone_scale", s.drop_zone_scale, 3, pos=True)
    ck.positive("scene.bin_wall_thickness", s.bin_wall_thickness)
    ck.choice("scene.other_objects", s.other_objects, OTHER_OBJECTS)
    if not 0 <= s.seed <= MAX_INT32:      # the sidebar's IntProperty holds no more (limits.MAX_INT32)
        ck.add("scene.seed", f"must be in 0..{MAX_INT32} (2^31-1), got {s.seed}", f"give a seed from 0 to {MAX_INT32}")
    if s.blend_file and ck.path("scene.blend_file", s.blend_file) and check_files:
        if not os.path.isfile(s.blend_file) or file_problem(s.blend_file, None):   # Blender reads it: any size
            ck.add("scene.blend_file", _not_found(s.blend_file), "give the path of an existing .blend")
        elif not s.blend_file.lower().endswith(".blend"):
            ck.add("scene.blend_file", f"not a .blend file: {s.blend_file}", "give a .blend file")
        else:
            _check_blend_header(ck, s.blend_file)


BLEND_MAGICS = (b"BLENDER", b"\x28\xb5\x2f\xfd", b"\x1f\x8b")   # plain, zstd (3.0+), gzip (older) .blend


def _check_blend_header(ck: _Checks, path: str) -> None:
    """The first bytes of a .blend: a file that is not one fails here, before Blender is started
    (the Blender preflight then reads the file itself: core/preflight.check_blend)."""
    try:
        head = read_regular(path, None, head=12)
    except DataPipeError as e:
        ck.add("scene.blend_file", str(e), "check the file's permissions")
        return
    if not head.startswith(BLEND_MAGICS):
        ck.add("scene.blend_file", f"{path} is not a Blender file (it starts with {_short(head[:7])}, not "
               "b'BLENDER' or a compressed .blend)", "give a .blend saved by Blender")


def _not_found(path: str) -> str:
    """Why an input file cannot be read: missing (or a dangling link), or there but not a regular file
    (a FIFO would block the reader, a device never end: io/input_files.py)."""
    return file_problem(path, None) or f"file not found: {path}"


def _check_mesh_path(ck: _Checks, path: str, filepath: str, check_files: bool) -> None:
    if not filepath:
        ck.add(path, "empty", "give the path of a mesh file (.obj, .ply, .stl, .glb, .gltf)")
        return
    if not ck.path(path, filepath):
        return
    suffix = Path(filepath).suffix.lower()
    if check_files and os.path.isdir(filepath):
        ck.add(path, f"is a folder, not a mesh file: {filepath}", "give the path of one mesh file inside it")
    elif suffix not in MESH_SUFFIXES:
        ck.add(path, f"not a mesh file: {filepath}", f"use one of {', '.join(MESH_SUFFIXES)}")
    elif check_files and file_problem(filepath, MAX_MESH_BYTES):
        problem = file_problem(filepath, MAX_MESH_BYTES)
        ck.add(path, problem, "check the path (relative paths are resolved against the preset's folder)"
               if problem.startswith("file not found") else "give a mesh file (a regular file within the limit "
               "in docs/INPUT_LIMITS.md)")
    elif check_files:
        for problem in mesh_ref_problems(filepath):    # a glTF's buffers, an OBJ's .mtl and textures
            ck.add(path, problem, "make the files the mesh names regular files beside it (re-export it from a "
                   "modeller, e.g. as one .glb); see docs/INPUT_LIMITS.md")


def _check_bop_entry(ck: _Checks, p: str, o: ObjectEntry, check_files: bool) -> None:
    from ..errors import DataPipeError
    from ..io.bop_models import bop_ids
    if not (isinstance(o.bop_obj_ids, list) and all(isinstance(i, int) and i >= 1 for i in o.bop_obj_ids)):
        ck.add(f"{p}.bop_obj_ids", f"expected a list of object ids >= 1, got {_short(o.bop_obj_ids)}",
               "list BOP object ids, e.g. [1, 5, 7], or [] for all")
    elif not o.bop_models:
        ck.add(f"{p}.bop_models", "empty, but bop_obj_ids is given", "give the BOP dataset's models folder")
    elif o.filepath:
        ck.add(f"{p}.filepath", "given together with bop_models", "give either a mesh file or a BOP models "
               "folder per entry")
    elif check_files:
        try:
            bop_ids(o, p)
        except DataPipeError as e:
            ck.add(*_split_field(str(e)))


def _check_shape_entry(ck: _Checks, p: str, o: ObjectEntry) -> None:
    """A procedural distractor (datapipe/shapes.py): no file, not annotated, its exact collision."""
    from ..shapes import problems as shape_problems
    for where, what, fix in shape_problems(o.shape, f"{p}.shape"):
        ck.add(where, what, fix)
    if o.filepath or o.bop_models or o.bop_obj_ids:
        ck.add(f"{p}.shape", "given together with a mesh file or BOP models folder",
               "give either a shape or a mesh file per entry")
    if o.annotate is not False:
        ck.add(f"{p}.annotate", "a procedural shape draws its size per instance, so no one model describes it "
               "in the ground truth", "set annotate: false (shapes are distractors)")
    if o.collision_shape != "AUTO":
        ck.add(f"{p}.collision_shape", f"{_short(o.collision_shape)} for a procedural shape, whose collision is "
               "exact (its convex hull; a tube: its wall segments)", "leave collision_shape \"AUTO\"")


def _check_symmetries(ck: _Checks, p: str, s) -> None:
    from ..errors import DataPipeError
    from ..io.symmetry import check_symmetries
    if isinstance(s, dict) and set(s) == {"tolerance"}:
        if not (_is_number(s["tolerance"]) and 0 < s["tolerance"] < 0.5):
            ck.add(f"{p}.symmetries.tolerance", f"got {_short(s['tolerance'])}", "give a fraction of the "
                   "diameter in (0, 0.5), e.g. 0.01")
    elif isinstance(s, dict):
        try:
            check_symmetries(s, f"{p}.symmetries")
        except DataPipeError as e:
            ck.add(*_split_field(str(e)))
    elif s not in ("auto", "detect", "none"):
        ck.add(f"{p}.symmetries", f"unknown value {_short(s)}", "use \"auto\", \"detect\", \"none\", "
               "{\"tolerance\": 0.01} or a dict of symmetries_discrete / symmetries_continuous")


def _check_objects(ck: _Checks, cfg: Config, check_files: bool) -> None:
    if not cfg.objects:
        ck.add("objects", "no objects to drop", "add at least one object entry (a mesh file)")
    for i, o in enumerate(cfg.objects):
        p = f"objects[{i}]"
        if o.shape is not None:
            _check_shape_entry(ck, p, o)
        elif o.bop_models or o.bop_obj_ids:
            _check_bop_entry(ck, p, o, check_files)
        else:
            _check_mesh_path(ck, f"{p}.filepath", o.filepath, check_files)
        if not isinstance(o.annotate, bool):
            ck.add(f"{p}.annotate", f"expected true or false, got {_short(o.annotate)}",
                   "give true (annotated) or false (a distractor)")
        _check_symmetries(ck, p, o.symmetries)
        if not 0 <= o.obj_id <= MAX_INT32:
            ck.add(f"{p}.obj_id", f"must be in 0..{MAX_INT32}, got {o.obj_id}", "give a BOP object id >= 1, or 0 for "
                   "the entry's position + 1")
        ck.positive(f"{p}.scale", o.scale)
        ck.positive(f"{p}.mass", o.mass)
        ck.choice(f"{p}.collision_shape", o.collision_shape, COLLISION_SHAPES)
        ck.choice(f"{p}.origin", o.origin, ORIGINS)
        ck.min_max(p, "min_instances", "max_instances", o.min_instances, o.max_instances)
        if o.max_instances > MAX_INSTANCES:
            ck.add(f"{p}.max_instances", f"{o.max_instances} instances is beyond what one bin holds",
                   f"use at most {MAX_INSTANCES} instances per object")
        if not 0 <= o.friction:
            ck.add(f"{p}.friction", f"must be >= 0, got {o.friction}", "give a friction >= 0")
        if not 0 <= o.restitution <= 1:
            ck.add(f"{p}.restitution", f"must be in 0..1, got {o.restitution}", "give a restitution in 0..1")
    if check_files:
        from ..io.bop_models import planned_obj_ids
        ids: dict[int, str] = {}
        for origin, k in planned_obj_ids(cfg):
            if k in ids:
                ck.add(origin.split(" ")[0] + ".obj_id", f"obj_id {k} is also the id of {ids[k]}",
                       "give each object a unique obj_id (0: its position + 1)")
            ids.setdefault(k, origin)
    if cfg.objects and sum(o.max_instances for o in cfg.objects) < 1:
        ck.add("objects", "every entry has max_instances = 0, so scenes would be empty",
               "give at least one entry max_instances >= 1")
    elif cfg.objects and sum(o.max_instances for o in cfg.objects if o.annotate is not False) < 1:
        ck.add("objects", "every part a scene can hold is a distractor (annotate: false), so its ground truth "
               "would be empty", "set annotate: true on at least one entry with max_instances >= 1")
    _check_object_names(ck, cfg)


def _check_object_names(ck: _Checks, cfg: Config) -> None:
    """Names Blender can hold whole with an instance number (text_rules), and unique ones."""
    for i, o in enumerate(cfg.objects):
        if (ck.has(f"objects[{i}].filepath") or ck.has(f"objects[{i}].shape")) and not o.name:
            continue                          # the name would come from a path already refused
        problem = name_problem(cfg.object_name(i), suffix="_000")   # instance k: f"{name}_{k:03d}"
        if problem is None and cfg.object_name(i).startswith("datapipe_"):
            problem = (f"{_short(cfg.object_name(i))} starts with 'datapipe_', the prefix of DataPipe's own objects "
                       "(templates, lights, the bin), whose names it could take", "give a name without that prefix")
        if problem is not None:
            what, fix = problem
            if not o.name:
                what, fix = f"the name taken from the file name, {what}", f"set objects[{i}].name: {fix}"
            ck.add(f"objects[{i}].name", what, fix)
    seen: dict[str, int] = {}
    for i, o in enumerate(cfg.objects):
        name = cfg.object_name(i)
        if name in seen:
            ck.add(f"objects[{i}].name", f"name {name!r} is already used by objects[{seen[name]}] (instance names "
                   "and annotations would collide)", "give this entry a unique name")
        seen.setdefault(name, i)


def _check_camera(ck: _Checks, cfg: Config, check_files: bool) -> None:
    c, s = cfg.camera, cfg.scene
    ck.positive("camera.focal_length", c.focal_length)
    ck.positive("camera.sensor_width", c.sensor_width)
    ck.choice("camera.sensor_fit", c.sensor_fit, SENSOR_FITS)
    ck.resolution("camera.resolution", c.resolution)
    ck.positive("camera.clip_start", c.clip_start)
    if c.clip_end <= c.clip_start:
        ck.add("camera.clip_end", f"clip_end ({c.clip_end}) <= clip_start ({c.clip_start})",
               "make clip_end > clip_start")
    else:
        ck.not_below("camera.clip_end", c.clip_end)
    _check_field_of_view(ck, "camera", c.focal_length, c.sensor_width, "sensor sees",
                         ": parts would be a few pixels or less",
                         "give a focal length of a real lens (industrial cameras: 4-50 mm)")
    pool = c.sampler.kind == "pool"
    if not c.poses and pool:
        ck.add("camera.poses", "no camera poses", "add at least one pose (location + quaternion wxyz)")
    for i, pose in enumerate(c.poses):
        if ck.vector(f"camera.poses[{i}].location", pose.location, 3) and pool:
            _check_pose_reaches_bin(ck, cfg, i)
        if ck.vector(f"camera.poses[{i}].rotation", pose.rotation, 4):
            if math.sqrt(sum(q * q for q in pose.rotation)) < 1e-6:
                ck.add(f"camera.poses[{i}].rotation", "zero quaternion", "give a unit quaternion (w, x, y, z)")
    if pool and c.poses and s.max_renders_per_scene > len(c.poses):
        ck.add("scene.max_renders_per_scene",
               f"{s.max_renders_per_scene} renders per scene but only {len(c.poses)} camera poses "
               "(poses are drawn without replacement within a scene)",
               "add camera poses or lower max_renders_per_scene")


def _check_pose_reaches_bin(ck: _Checks, cfg: Config, i: int) -> None:
    """A pool pose from which no part can be rendered: every point where parts can lie is beyond
    camera.clip_end in depth. A point seen at angle theta off the optical axis at distance d has depth
    d cos(theta) >= d cos(theta_max), theta_max the half diagonal field of view; parts lie within a
    sphere of radius R about the drop zone's centre (twice the zone's half diagonal times the largest
    bin scale: a margin for parts heaped above the zone), so (distance to the centre - R) cos(theta_max) > clip_end means nothing of the bin is
    drawn. (A pose 2^63 m away was blamed on objects[i].scale by the mesh preflight: "0 px".)"""
    c, s = cfg.camera, cfg.scene
    res = c.resolution
    if not (len(res) == 2 and min(res) >= 1 and len(s.drop_zone_loc) == 3 and len(s.drop_zone_scale) == 3
            and c.focal_length > 0 and c.sensor_width > 0 and c.sensor_fit in SENSOR_FITS
            and len(s.bin_size_scale) == 2 and len(s.bin_wall_scale) == 2) or s.blend_file:
        return                     # their own rules report them; a .blend's drop_zone object moves the bin
    if c.intrinsics is not None and not (len(c.intrinsics) == 4 and all(_finite(v) for v in c.intrinsics)):
        return                     # _check_lens says why
    from ..geometry import camera_intrinsics
    K = camera_intrinsics(c)       # camera.intrinsics when given (a calibration)
    fx, fy = float(K[0, 0]), float(K[1, 1])
    if not (math.isfinite(fx) and math.isfinite(fy) and fx > 0 and fy > 0):
        return
    cos_max = math.cos(math.atan(math.hypot(res[0] / 2 / fx, res[1] / 2 / fy)))
    grow = max(1.0, *s.bin_size_scale, *s.bin_wall_scale)
    R = 2 * math.sqrt(sum(h * h for h in s.drop_zone_scale)) * grow
    d = math.dist(c.poses[i].location, s.drop_zone_loc)
    if math.isfinite(d) and (d - R) * cos_max > c.clip_end:
        ck.add(f"camera.poses[{i}].location", f"the camera is {d:.3g} m from the drop zone's centre: every part "
               f"would be beyond camera.clip_end ({c.clip_end:g} m), so nothing of the bin is rendered",
               "give the camera's location in metres in the world, near the bin (see scene.drop_zone_loc), or "
               "raise camera.clip_end")


def _check_render(ck: _Checks, cfg: Config, check_files: bool) -> None:
    r = cfg.render
    ck.choice("render.engine", r.engine, ENGINES)
    ck.choice("render.device", r.device, DEVICES)
    ck.int_range("render.samples", r.samples, 1, MAX_SAMPLES, "samples")
    ck.choice("render.denoise_prefilter", r.denoise_prefilter, DENOISE_PREFILTERS)
    ck.choice("render.denoise_quality", r.denoise_quality, DENOISE_QUALITIES)
    ck.choice("render.sampling_pattern", r.sampling_pattern, SAMPLING_PATTERNS)
    if r.threads < 0:
        ck.add("render.threads", f"must be >= 0, got {r.threads}", "use 0 for all cores")
    ck.at_most("render.threads", r.threads, 1024, "more threads than any machine has")
    ck.int_range("render.max_bounces", r.max_bounces, 0, 1024, "bounces")
    if not (0.0 <= r.adaptive_threshold < 1.0):
        ck.add("render.adaptive_threshold", f"must be in [0, 1), got {r.adaptive_threshold}",
               "use 0 (off) or a noise threshold such as 0.01")
    if r.light_power < 0:
        ck.add("render.light_power", f"must be >= 0, got {r.light_power}", "give a power >= 0 W")
    if not r.outputs:
        ck.add("render.outputs", "no outputs requested, so a run would write nothing",
               f"list some of {', '.join(OUTPUT_KINDS)}")
    for i, k in enumerate(r.outputs):
        ck.choice(f"render.outputs[{i}]", k, OUTPUT_KINDS)
    if len(set(r.outputs)) != len(r.outputs):
        ck.add("render.outputs", f"duplicate entries in {r.outputs}", "list each output once")
    for i, k in enumerate(r.outputs):
        if k in SL_OUTPUT_KINDS and not cfg.structured_light.enabled:
            ck.add(f"render.outputs[{i}]", f"{k!r} is the structured-light scanner's output, but structured "
                   "light is off", f"set structured_light.enabled to true, or drop {k!r} from render.outputs")


def _check_simulation(ck: _Checks, cfg: Config, check_files: bool) -> None:
    m = cfg.simulation
    ck.int_range("simulation.substeps", m.substeps, 1, 1000, "substeps")
    if m.max_substeps < m.substeps:
        ck.add("simulation.max_substeps", f"must be >= simulation.substeps ({m.substeps}), got {m.max_substeps}",
               "give a maximum at least as large as the minimum")
    ck.at_most("simulation.max_substeps", m.max_substeps, 10_000, "more substeps than any scene needs")
    ck.int_range("simulation.solver_iterations", m.solver_iterations, 1, 1000, "iterations")
    ck.int_range("simulation.max_frames", m.max_frames, 1, 100_000, "frames")
    ck.positive("simulation.settle_speed", m.settle_speed)
    ck.int_range("simulation.settle_frames", m.settle_frames, 1, 100_000, "frames")
    if m.layer_gap < 0:
        ck.add("simulation.layer_gap", f"must be >= 0, got {m.layer_gap}", "give a gap >= 0 m")
    _check_redraw(m, ck.add)


def _check_redraw(m: SimulationConfig, add) -> None:
    if not (math.isfinite(m.redraw_lost_share) and 0.0 <= m.redraw_lost_share <= 1.0):
        add("simulation.redraw_lost_share", f"must be in [0, 1], got {m.redraw_lost_share}",
            "give a share of parts between 0 and 1 (1 never redraws)")
    if not 0 <= m.redraw_attempts <= 10:
        add("simulation.redraw_attempts", f"must be in 0..10, got {m.redraw_attempts}",
            "give a small number of retries (each costs one more simulation)")


def _check_output(ck: _Checks, cfg: Config, check_files: bool) -> None:
    o, r = cfg.output, cfg.render
    if not o.path:
        ck.add("output.path", "empty", "give an output folder")
    elif output_folder_problem(o.path):
        ck.add("output.path", *output_folder_problem(o.path))
    for i, f in enumerate(o.formats):
        ck.choice(f"output.formats[{i}]", f, FORMATS)
    if not o.formats:
        ck.add("output.formats", "no output format", "use [\"native\"] and/or \"bop\"")
    for flag in ("xyz_crop", "amodal_coco"):
        if getattr(o, flag) is not True and getattr(o, flag) is not False:
            ck.add(f"output.{flag}", f"{getattr(o, flag)!r} is not true or false", "give true or false")
        elif getattr(o, flag) and "bop" not in o.formats:
            ck.add(f"output.{flag}", "is written into the BOP export, which output.formats does not ask for",
                   f"add \"bop\" to output.formats, or set output.{flag} to false")
    if "bop" in o.formats:
        for need in ("rgb", "depth", "mask"):
            if need not in r.outputs:
                ck.add("render.outputs", f"the BOP format needs the {need!r} output",
                       f"add {need!r} to render.outputs or drop 'bop' from output.formats")
    if o.bop_sensor is not None:
        from ..io.bop_sensor import sensor_name_problem
        bad = sensor_name_problem(o.bop_sensor)
        if bad:
            ck.add("output.bop_sensor", *bad)


def _check_variety(ck: _Checks, cfg: Config, check_files: bool) -> None:
    """Per-scene variety: bin shape ranges, the camera sampler, the lighting ranges."""
    s = cfg.scene
    ck.problems += _range_problems("scene.bin_size_scale", s.bin_size_scale, lo_bound=0.05, hi_bound=20.0)
    ck.problems += _range_problems("scene.bin_wall_scale", s.bin_wall_scale, lo_bound=0.05, hi_bound=20.0)
    if s.fill is not None:
        from ..draws.fill import MAX_FILL
        ck.problems += _range_problems("scene.fill", s.fill, lo_bound=0.0, hi_bound=MAX_FILL)
    ck.problems += _sampler_problems(cfg)
    ck.problems += _lighting_problems(cfg.lighting)
    ck.problems += _picks_problems(cfg)


def _picks_problems(cfg: Config) -> list[Problem]:
    """scene.picks: a known order, steps that remove parts the pile holds (datapipe/draws/picks.py)."""
    pk = cfg.scene.picks
    if pk is None:
        return []
    from ..draws.picks import fewest_parts, most_parts
    p = "scene.picks"
    out = []
    if pk.order not in PICK_ORDERS:
        out.append(Problem(f"{p}.order", f"unknown value {pk.order!r}", f"use one of {', '.join(PICK_ORDERS)}"))
    elif pk.order == "visible" and "mask" not in cfg.render.outputs:
        out.append(Problem(f"{p}.order", "'visible' ranks parts by their visible fraction, which needs the mask",
                           "add 'mask' to render.outputs, or use order 'top' or 'random'"))
    if pk.per_step < 1:
        out.append(Problem(f"{p}.per_step", f"must be >= 1, got {pk.per_step}", "remove at least one part per step"))
    if pk.until < 0:
        out.append(Problem(f"{p}.until", f"must be >= 0, got {pk.until}", "give the parts left at the end (0: all picked)"))
    if out or not cfg.objects:
        return out
    most, fewest = most_parts(cfg), fewest_parts(cfg)
    if pk.until >= fewest:
        out.append(Problem(f"{p}.until", f"{pk.until} parts would remain, but a pile holds as few as {fewest} "
                           "(the objects' min_instances): its sequence would pick nothing",
                           f"give until below {fewest}, or raise the objects' min_instances"))
    elif pk.per_step > most - pk.until:
        out.append(Problem(f"{p}.per_step", f"{pk.per_step} parts per step is more than a pile holds above "
                           f"until ({most} - {pk.until} = {most - pk.until})",
                           f"give per_step at most {most - pk.until}, or lower until"))
    return out


def _sampler_problems(cfg: Config) -> list[Problem]:
    """camera.sampler: kind, ranges, and ranges that can lose the bin from view."""
    sm, c = cfg.camera.sampler, cfg.camera
    if sm.kind not in SAMPLER_KINDS:
        return [Problem("camera.sampler.kind", f"unknown value {sm.kind!r}", f"use one of {', '.join(SAMPLER_KINDS)}")]
    if sm.kind == "pool":
        return []
    p = "camera.sampler"
    out = _range_problems(f"{p}.distance", sm.distance, lo_bound=1e-3, unit=" m")
    out += _range_problems(f"{p}.tilt_deg", sm.tilt_deg, lo_bound=0.0, hi_bound=89.0, unit=" deg")
    out += _range_problems(f"{p}.azimuth_deg", sm.azimuth_deg)
    out += _range_problems(f"{p}.roll_deg", sm.roll_deg)
    if not (math.isfinite(sm.target_jitter) and sm.target_jitter >= 0):
        out.append(Problem(f"{p}.target_jitter", f"must be >= 0, got {sm.target_jitter}", "give a jitter >= 0 m"))
    if out:
        return out
    if min(sm.distance) <= c.clip_start or max(sm.distance) >= c.clip_end:
        out.append(Problem(f"{p}.distance", f"{sm.distance} m reaches outside the clip range "
                           f"({c.clip_start:g}..{c.clip_end:g} m): the target would be clipped",
                           "keep the distances between camera.clip_start and camera.clip_end"))
    res, fit = c.resolution, c.sensor_fit
    intrinsics_ok = c.intrinsics is None or (len(c.intrinsics) == 4 and all(_finite(v) for v in c.intrinsics)
                                             and min(c.intrinsics[:2]) > 0)   # else _check_lens says why
    if len(res) == 2 and min(res) >= 1 and c.focal_length > 0 and c.sensor_width > 0 and fit in SENSOR_FITS \
            and intrinsics_ok:
        from ..draws.camera_sampler import view_problems
        from ..geometry import camera_intrinsics
        K = camera_intrinsics(c)            # camera.intrinsics when given (a calibration)
        fx, fy = float(K[0, 0]), float(K[1, 1])
        if not (math.isfinite(fx) and math.isfinite(fy) and fx > 0 and fy > 0):
            return out        # a lens of 1e-300 mm: the field-of-view rule refuses it (no numpy warning here)
        half_fov = math.degrees(min(math.atan(res[0] / 2 / fx), math.atan(res[1] / 2 / fy)))
        s = cfg.scene
        if len(s.drop_zone_scale) == 3 and len(s.bin_size_scale) == 2 and len(s.bin_wall_scale) == 2:
            walls = 2 * s.drop_zone_scale[2] * max(s.bin_wall_scale) if s.make_bin else 0.0   # highest walls
            floor = [h * min(s.bin_size_scale) for h in s.drop_zone_scale[:2]]              # smallest bin
            out += [Problem(*t) for t in view_problems(sm, floor, walls, half_fov)]
    return out


def _lighting_problems(li: LightingConfig | None) -> list[Problem]:
    if li is None:
        return []
    p = "lighting"
    out = _range_problems(f"{p}.key_power", li.key_power, lo_bound=0.0, unit=" W")
    out += _range_problems(f"{p}.key_color_temperature", li.key_color_temperature, lo_bound=1000.0,
                           hi_bound=40000.0, unit=" K")
    out += _range_problems(f"{p}.key_size", li.key_size, lo_bound=1e-3, unit=" m")
    out += _range_problems(f"{p}.ambient", li.ambient, lo_bound=0.0)
    if not (math.isfinite(li.key_position_jitter) and li.key_position_jitter >= 0):
        out.append(Problem(f"{p}.key_position_jitter", f"must be >= 0, got {li.key_position_jitter}",
                           "give a jitter >= 0 m"))
    return out


def _check_materials(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """objects[i].material and scene.bin_material (name, dict or list)."""
    for i, o in enumerate(cfg.objects):
        problem = material_problem(o.material)
        if problem is not None:
            ck.add(f"objects[{i}].material", *problem)
    problem = material_problem(cfg.scene.bin_material)
    if problem is not None:
        ck.add("scene.bin_material", *problem)


def _check_device(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """device (a known scanner) and binning (one it offers)."""
    from ..devices import device_problem, is_calibration_path
    if is_calibration_path(cfg.device):     # a calibration file: read (and checked) when the preset was parsed
        return
    problem = device_problem(cfg.device, cfg.binning)
    if problem is not None:
        ck.problems.append(problem)


def _check_lens(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """camera.intrinsics / camera.distortion / projector.intrinsics (a calibration's fields)."""
    from .calibration import config_problems, working_distance_problems
    ck.problems.extend(config_problems(cfg))
    if not ck.has("camera") and not ck.has("projector"):
        ck.problems.extend(working_distance_problems(cfg))


# The steps validate() runs, in order. A new field's checks go into a small step function here.
VALIDATION_STEPS = (_check_scene, _check_objects, _check_camera, _check_lens, _check_variety, _check_projector,
                    _check_structured_light, _check_render, _check_simulation, _check_output, _check_materials,
                    _check_textures, _check_environment,
                    _check_device)
