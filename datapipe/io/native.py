"""The native annotations: one scene.json per scene (docs/ARCHITECTURE.md), written last and atomically
so that its existence with `"complete": true` means the scene is complete."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import layout
from .files import write_json_atomic


def write_scene(scene_dir: Path, scene: dict) -> None:
    write_json_atomic(Path(scene_dir) / layout.SCENE_FILE, scene)


class NativeWriter:
    """scene.json of each finished scene (the run's own record: always written, whatever the formats)."""

    name = "native"

    def __init__(self, out_dir: str | Path):
        self.out = Path(out_dir)

    def start(self) -> None:
        pass

    def has_scene(self, scene_dir: Path, scene: dict) -> bool:
        return layout.scene_complete(scene_dir)

    def add_scene(self, scene_dir: Path, scene: dict) -> None:
        write_scene(scene_dir, scene)

    def finish(self) -> dict:
        return {}


def write_render_maps(render_dir: Path, maps: dict) -> dict[str, Path]:
    """Write one render's output maps into its folder under the layout's names, in the order given:
    {kind: {channel: (H, W) array}} as EXR, {kind: uint8 image (BGR or grey)} as PNG. Returns
    {kind: path}."""
    from .exr import write_exr
    from .files import imwrite_atomic

    render_dir = Path(render_dir)
    files = {}
    for kind, data in maps.items():
        path = render_dir / layout.RENDER_FILES[kind]
        if path.suffix == ".exr":
            write_exr(path, data)
        else:
            imwrite_atomic(path, data)
        files[kind] = path
    return files


# ------------------------------------------------------------------------------------------------
# the records of scene.json (docs/ARCHITECTURE.md), in their key order

def object_record(part) -> dict:
    """A part (name, filename, obj_id, mask_index, material) as scene.json lists it."""
    return {"name": part.name, "filename": part.filename, "obj_id": part.obj_id, "mask_index": part.mask_index,
            "material": part.material}


def scene_record(scene_id: int, seed: int, start) -> dict:
    """scene.json of a scene whose parts have dropped (`start`: a core.world.SceneStart); renders follow."""
    return {"scene_id": scene_id, "name": layout.scene_name(scene_id), "seed": seed,
            "simulation": start.simulation, **start.drawn, "objects": [object_record(p) for p in start.parts], "renders": []}


def render_record(render_id: int, image_id: int, pose_index: int, seed: int, view, parts, scene_dir: Path) -> dict:
    """One render of scene.json from what the world made (`view`: a core.world.View) and the scene's parts:
    poses in the OpenCV (T_cam_obj) and Blender (cam2obj_pose) camera frames, visible pixel counts."""
    rec = {
        "render_id": render_id, "name": layout.render_name(render_id), "image_id": image_id,
        "pose_index": None if pose_index is None else int(pose_index), "K": view.K,
        **({"distortion": list(view.distortion)} if getattr(view, "distortion", None) is not None else {}),  # a lens only
        "resolution": list(view.resolution),
        "T_world_cam": view.T_world_cam, "T_world_blcam": view.T_world_blcam, "seed": seed,
        "files": {k: str(Path(p).relative_to(scene_dir)) for k, p in view.files.items()},
        "objects": [],
    }
    if view.camera_sampler is not None:
        rec["camera_sampler"] = view.camera_sampler
    if getattr(view, "lighting", None) is not None:        # lighting.per_render only
        rec["lighting"] = view.lighting
    T_cam_world = np.linalg.inv(view.T_world_cam)
    T_blcam_world = np.linalg.inv(view.T_world_blcam)
    for part, T_world_obj in zip(parts, view.T_world_obj):
        o = object_record(part)
        o["T_cam_obj"] = T_cam_world @ T_world_obj
        o["cam2obj_pose"] = T_blcam_world @ T_world_obj
        o["px_count_visib"] = int(np.count_nonzero(view.mask == part.mask_index)) if view.mask is not None else None
        rec["objects"].append(o)
    if view.structured_light is not None:
        rec["structured_light"] = view.structured_light
    return rec
