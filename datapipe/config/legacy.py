"""The original DataPipe add-on's input dict (layout in docs/CONVENTIONS.md) <-> Config."""
from __future__ import annotations

from ..errors import ConfigError, Problem
from ..text_rules import short as _short
from .checks import _join
from .limits import COLLISION_SHAPES
from .schema import CameraPose, Config, ObjectEntry


_POSE_LIST_KEYS = ("world2cam_pose_list", "wrlld2cam_pose_list", "wrl2cam_pose_list")


def from_legacy_dict(d: dict) -> Config:
    """Map the original DataPipe input dict (layout in docs/CONVENTIONS.md) onto a Config.

    Every value is converted through `_Legacy`, so a wrong type anywhere is a ConfigError naming
    the pickle's own key path, never a traceback."""
    if not isinstance(d, dict):
        raise ConfigError(Problem("<pickle>", f"expected a dict, got {type(d).__name__}",
                                  "give an original DataPipe inputs pickle"))
    lg = _Legacy()
    known = {"camera", "projector", "scene", "objects", "output"}
    for k in d:
        if k not in known:
            lg.add(_join("", k), "unknown section in the legacy pickle", f"known sections: {', '.join(sorted(known))}")
    cfg = Config()
    cam = lg.section(d, "camera")
    pose_key = next((k for k in _POSE_LIST_KEYS if k in cam), None)
    if pose_key is not None:
        cfg.camera.poses = []
        for i, pose in enumerate(lg.items(cam, pose_key, f"camera.{pose_key}")):
            loc = lg.numbers(pose, "location", f"camera.{pose_key}[{i}]", 3)
            rot = lg.numbers(pose, "rotation", f"camera.{pose_key}[{i}]", 4)
            if loc is not None and rot is not None:
                cfg.camera.poses.append(CameraPose(location=loc, rotation=rot))
    for key in ("focal_length", "sensor_width"):
        lg.number(cam, key, "camera", cfg.camera, key)
    if "resolution" in cam:
        hw = lg.numbers(cam, "resolution", "camera", 2, int)
        if hw is not None:
            cfg.camera.resolution = [hw[1], hw[0]]          # the original stored [height, width]
    if "is_structured_light" in cam:
        cfg.structured_light.enabled = bool(cam["is_structured_light"])

    proj = lg.section(d, "projector")
    pose = lg.section(proj, "proj2cam_pose", "projector")
    if pose:
        cfg.projector.location = lg.numbers(pose, "location", "projector.proj2cam_pose", 3) or cfg.projector.location
        cfg.projector.rotation = lg.numbers(pose, "rotation", "projector.proj2cam_pose") or cfg.projector.rotation
    for key in ("focal_length", "sensor_width"):
        lg.number(proj, key, "projector", cfg.projector, key)
    if "resolution" in proj:
        hw = lg.numbers(proj, "resolution", "projector", 2, int)
        if hw is not None:
            cfg.projector.resolution = [hw[1], hw[0]]

    sc = lg.section(d, "scene")
    for key in ("num_renders", "max_renders_per_scene", "min_renders_per_scene"):
        lg.number(sc, key, "scene", cfg.scene, key, int)
    for key in ("drop_zone_loc", "drop_zone_scale"):
        if key in sc:
            setattr(cfg.scene, key, lg.numbers(sc, key, "scene", 3) or getattr(cfg.scene, key))

    objs = lg.section(d, "objects")
    for i, o in enumerate(lg.items(objs, "objects_list", "objects.objects_list")):
        p = f"objects.objects_list[{i}]"
        if not isinstance(o, dict) or "filepath" not in o:
            lg.add(p, "needs at least 'filepath'", "fix or remove this entry")
            continue
        if not isinstance(o["filepath"], str):
            lg.add(f"{p}.filepath", f"expected a path string, got {_short(o['filepath'])}", "give the mesh's path")
            continue
        e = ObjectEntry(filepath=o["filepath"])
        for src, dst, conv in (("scale", "scale", float), ("mass", "mass", float), ("min", "min_instances", int),
                               ("max", "max_instances", int)):
            lg.number(o, src, p, e, dst, conv)
        e.collision_shape = o.get("collision_shape", e.collision_shape)
        if not isinstance(e.collision_shape, str):
            lg.add(f"{p}.collision_shape", f"expected a string, got {_short(e.collision_shape)}",
                   f"use one of {', '.join(COLLISION_SHAPES)}")
        if "max" not in o:
            e.max_instances = 1                              # the original's default
        cfg.objects.append(e)
    out = lg.section(d, "output")
    if "path" in out:
        if isinstance(out["path"], str):
            cfg.output.path = out["path"]
        else:
            lg.add("output.path", f"expected a folder path, got {_short(out['path'])}", "give the output folder")
    if lg.problems:
        raise ConfigError(lg.problems)
    return cfg


class _Legacy:
    """Typed reads from the original's dicts; each bad value becomes a Problem at its key path."""

    def __init__(self):
        self.problems: list[Problem] = []

    def add(self, path, msg, fix) -> None:
        self.problems.append(Problem(path, msg, fix))

    def section(self, d: dict, key: str, parent: str = "") -> dict:
        v = d.get(key) or {}
        if not isinstance(v, dict):
            self.add(_join(parent, key), f"expected a dict, got {type(v).__name__}", "give this section as a dict")
            return {}
        return v

    def items(self, d: dict, key: str, path: str) -> list:
        v = d.get(key) or []
        if not isinstance(v, (list, tuple)):
            self.add(path, f"expected a list, got {type(v).__name__}", "give a list")
            return []
        return list(v)

    def _convert(self, v, conv, path):
        try:
            if isinstance(v, (bool, str, bytes)) or not isinstance(v, (int, float)):
                raise TypeError
            x = conv(v)
            if conv is int and (x != v or not -2**63 <= x < 2**63):
                raise ValueError
            return x
        except (TypeError, ValueError, OverflowError):
            what = "a whole number" if conv is int else "a number"
            self.add(path, f"expected {what}, got {_short(v)}", f"give {what}")
            return None

    def number(self, d: dict, key: str, parent: str, target, attr: str, conv=float) -> None:
        if key in d:
            x = self._convert(d[key], conv, _join(parent, key))
            if x is not None:
                setattr(target, attr, x)

    def numbers(self, d, key: str, parent: str, n: int | None = None, conv=float) -> list | None:
        path = _join(parent, key)
        v = d.get(key) if isinstance(d, dict) else None
        if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n):
            self.add(path, f"expected {n or 'a list of'} numbers, got {_short(v)}",
                     f"give {n or 'the'} numbers as a list")
            return None
        xs = [self._convert(x, conv, f"{path}[{i}]") for i, x in enumerate(v)]
        return None if any(x is None for x in xs) else xs


def to_legacy_dict(cfg: Config) -> dict:
    """The original's input dict, for users who still drive the old add-on."""
    return {
        "camera": {"world2cam_pose_list": [{"rotation": list(p.rotation), "location": list(p.location)}
                                           for p in cfg.camera.poses],
                   "focal_length": cfg.camera.focal_length, "sensor_width": cfg.camera.sensor_width,
                   "resolution": [cfg.camera.resolution[1], cfg.camera.resolution[0]],
                   "is_structured_light": cfg.structured_light.enabled},
        "projector": {"proj2cam_pose": {"rotation": list(cfg.projector.rotation),
                                        "location": list(cfg.projector.location)},
                      "focal_length": cfg.projector.focal_length, "sensor_width": cfg.projector.sensor_width,
                      "resolution": [cfg.projector.resolution[1], cfg.projector.resolution[0]]},
        "scene": {"num_renders": cfg.scene.num_renders,
                  "max_renders_per_scene": cfg.scene.max_renders_per_scene,
                  "min_renders_per_scene": cfg.scene.min_renders_per_scene,
                  "drop_zone_loc": list(cfg.scene.drop_zone_loc),
                  "drop_zone_scale": list(cfg.scene.drop_zone_scale)},
        "objects": {"objects_list": [{"filepath": o.filepath, "scale": o.scale, "mass": o.mass,
                                      "collision_shape": o.collision_shape, "max": o.max_instances,
                                      "min": o.min_instances} for o in cfg.objects]},
        "output": {"path": cfg.output.path},
    }
