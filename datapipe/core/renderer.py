"""Cycles setup, the native view layer and its passes, the compositor, and one render -> files.

Once per run, `Renderer.setup()` configures Cycles, colour management for exact linear data, the
native view layer ("datapipe") with only the passes the config's outputs need, and the compositor:
Render Layers -> File Output writing ONE multilayer float32 EXR per render into the render folder
(temporary name `_passes`). Per render, `Renderer.render(render_dir, seed)` renders, reads that EXR
back, writes the final files of docs/ARCHITECTURE.md and deletes it:

    rgb.png      8-bit sRGB (the standard sRGB OETF of the linear combined image = view transform
                 Standard), written by cv2
    depth.exr    "Z": planar depth along the camera z axis, m; NaN where no surface was hit
    normals.exr  "X","Y","Z": unit normals in the OpenCV camera frame; 0 where nothing was hit
    mask.exr     "Y": the pass_index of the visible object (0 = background)
    object_coords.exr  "X","Y","Z": model coordinates (m) of the part at the pixel centre; NaN off
                 parts (only when asked for: shader AOVs, see core/object_coords.py)

Facts verified by rendering with bpy 5.0.1 (tests/blender/test_renderer.py keeps them checked):
EXR row 0 is the top of the image; Cycles' Z pass is planar depth (not ray length); depth and
object index come from the pixel centre (seed- and sample-count independent, no mixing at edges),
while the Normal pass is averaged over all samples (mixed at edges); the Normal pass is in world
space; background depth is 1e10.

The structured-light fringes are rendered in a call of their own (core/structured_light.py): they
need another pixel filter and resolution than the native layer.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import bpy

from . import compat, object_coords
from ..config import Config
from ..errors import DataPipeError
from ..world import SILENT, Reporter
from ..io.files import make_dirs
from ..io.native import write_render_maps
from .objects import OBJECTS_COLLECTION

NATIVE_LAYER = "datapipe"
TEMP_BASENAME = "_passes"           # the File Output's per-render multilayer EXR (no braces!)
NO_HIT_DEPTH = 1e9                  # Cycles writes 1e10 where a ray hits nothing

# Native File Output layers: config output -> (EXR layer name, Render Layers pass, socket type)
_NATIVE_ITEMS = {
    "rgb": ("Image", "image", "RGBA"),
    "depth": ("Depth", "depth", "FLOAT"),
    "normals": ("Normal", "normal", "VECTOR"),
    "mask": ("IndexOB", "index", "FLOAT"),
}
_PASS_FLAGS = {"depth": "use_pass_z", "normals": "use_pass_normal", "mask": "use_pass_object_index"}
_OUTPUTS = ("rgb", "depth", "normals", "mask", "object_coords")   # the order their files are written in
# object_coords: File Output layer -> (AOV, socket type); see core/object_coords.py
_COORD_ITEMS = {"ObjectXYZ": (object_coords.COORDS_AOV, "RGBA"), "ObjectHit": (object_coords.HIT_AOV, "FLOAT")}
_CHANNELS = {"FLOAT": ("V",), "VECTOR": ("X", "Y", "Z"), "RGBA": ("R", "G", "B", "A")}


@dataclass
class RenderOutput:
    """What one render produced. Arrays are None when their output was not asked for."""
    files: dict[str, Path]                      # kind ("rgb", "depth", ...) -> written file
    depth: np.ndarray | None = None             # (H, W) float32, m, NaN = no hit
    mask: np.ndarray | None = None              # (H, W) int32 pass_index, 0 = background
    normals: np.ndarray | None = None           # (H, W, 3) float32, OpenCV camera frame
    rgb: np.ndarray | None = None               # (H, W, 3) uint8 sRGB
    object_coords: np.ndarray | None = None     # (H, W, 3) float32 model coordinates, m; NaN off parts
    seconds: float = 0.0                        # wall time of the Cycles render itself
    T_world_cam: np.ndarray | None = None       # camera pose the render was made from


def srgb_oetf(linear: np.ndarray) -> np.ndarray:
    """The standard sRGB encoding (IEC 61966-2-1) of linear values, clipped to [0, 1]."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def linear_to_srgb8(linear_rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear -> (H, W, 3) uint8 sRGB, what Blender's Standard view transform shows."""
    return np.rint(srgb_oetf(linear_rgb) * 255.0).astype(np.uint8)


class Renderer:
    """Cycles + passes + compositor, configured once per run; `render()` once per camera pose."""

    def __init__(self, cfg: Config, scene, camera, progress: Reporter = SILENT):
        self.cfg = cfg
        self.progress = progress       # where its Cycles calls and writes are reported (the run's tracker)
        self.scene = scene
        self.camera = camera
        self.outputs: list[str] = [k for k in _OUTPUTS if k in cfg.render.outputs]
        self.view_layer = None
        self.coords_layer = None                         # the view layer of the object_coords AOVs
        self.device: str | None = None                   # set by setup(): "CPU" or the GPU backend
        self.tree = None
        self.file_output = None
        self._rl_nodes: dict[str, object] = {}           # view layer name -> Render Layers node
        self._items: dict[str, tuple[str, str, str]] = {}  # EXR layer -> (view layer, pass, socket type)

    # -- once per run -----------------------------------------------------------------------------
    def setup(self) -> "Renderer":
        self._setup_cycles()
        compat.set_linear_color_management(self.scene)
        self._setup_native_layer()
        self._build_compositor()
        return self

    def _setup_cycles(self) -> None:
        sc, r = self.scene, self.cfg.render
        sc.render.engine = compat.engine_id(r.engine)
        self.device = compat.set_cycles_device(sc, r.device)    # "CPU", or the GPU backend used
        cy = sc.cycles
        cy.samples = int(r.samples)
        if r.sampling_pattern != "SCENE":          # checked here, set only around the native call (render())
            with compat.sampling_pattern(cy, r.sampling_pattern):
                pass
        # adaptive sampling off: `samples` means what it says, a fixed noise level; with a threshold
        # Cycles stops a pixel's sampling once its noise estimate is below it
        cy.use_adaptive_sampling = r.adaptive_threshold > 0
        if r.adaptive_threshold > 0:
            cy.adaptive_threshold = float(r.adaptive_threshold)
            cy.adaptive_min_samples = 0                  # Cycles' automatic minimum
        cy.max_bounces = int(r.max_bounces)
        cy.use_denoising = bool(r.denoise)
        if r.denoise:                 # OpenImageDenoise runs on the CPU; guided by albedo and normals
            cy.denoiser = "OPENIMAGEDENOISE"
            cy.denoising_input_passes = "RGB_ALBEDO_NORMAL"
            compat.set_denoiser_settings(cy, r.denoise_prefilter, r.denoise_quality)
        sc.render.use_persistent_data = bool(r.persistent_data)
        cy.use_preview_denoising = False
        cy.time_limit = 0.0
        if r.threads > 0:
            sc.render.threads_mode = "FIXED"
            sc.render.threads = int(r.threads)
        else:
            sc.render.threads_mode = "AUTO"
        sc.render.film_transparent = False
        sc.render.use_compositing = True
        sc.render.use_sequencer = False
        sc.render.use_motion_blur = False

    def _setup_native_layer(self) -> None:
        layers = self.scene.view_layers
        vl = layers.get(NATIVE_LAYER) or layers[0]
        vl.name = NATIVE_LAYER
        vl.use = True
        for other in layers:                 # layers from a .blend would each cost a full render
            if other != vl:
                other.use = False
        for kind, flag in _PASS_FLAGS.items():
            setattr(vl, flag, kind in self.outputs)
        # Depth, object index and (with one sample) normals come from the pixel centre; without an
        # RGB output the extra samples would only be averaged into the normals.
        vl.samples = 0 if "rgb" in self.outputs else 1
        self.view_layer = vl
        old = layers.get(object_coords.COORDS_LAYER)
        if "object_coords" in self.outputs:
            # one sample, so the pixel centre (see core/object_coords.py): the native layer when it
            # has one sample, else a layer of its own in the same render call
            if vl.samples == 1:
                object_coords.add_aovs(vl)
                self.coords_layer = vl
            else:
                self.coords_layer = object_coords.coords_layer(self.scene)
        if old is not None and old != self.coords_layer:       # from an earlier run saved in the .blend
            layers.remove(old)

    def _build_compositor(self) -> None:
        self.tree = compat.compositor_tree(self.scene, clear=True)
        self._rl_nodes.clear()
        self._items.clear()
        self.file_output = compat.new_file_output(self.tree, bpy.app.tempdir or "/tmp", TEMP_BASENAME)
        rl = self._render_layers(self.view_layer)
        compat.add_compositor_sink(self.tree, compat.rl_socket(rl, "image"))
        for kind in self.outputs:
            if kind == "object_coords":
                for item, (aov, socket_type) in _COORD_ITEMS.items():
                    self._link(self.coords_layer, item, aov, socket_type)
                continue
            item, pass_kind, socket_type = _NATIVE_ITEMS[kind]
            self._link(self.view_layer, item, pass_kind, socket_type)

    def _render_layers(self, view_layer):
        rl = self._rl_nodes.get(view_layer.name)
        if rl is None:
            rl = compat.render_layers_node(self.tree, self.scene, view_layer.name,
                                           name=f"datapipe_rl_{len(self._rl_nodes)}")
            rl.location = (-400, -300 * len(self._rl_nodes))
            self._rl_nodes[view_layer.name] = rl
        return rl

    def _link(self, view_layer, item: str, pass_kind: str, socket_type: str) -> None:
        if item in self._items:
            raise ValueError(f"File Output layer {item!r} already exists")
        socket = compat.rl_socket(self._render_layers(view_layer), pass_kind)
        self.tree.links.new(socket, compat.file_output_add_input(self.file_output, item, socket_type))
        self._items[item] = (view_layer.name, pass_kind, socket_type)

    def teardown(self) -> None:
        """Remove the object-coordinate view layer (a layer of its own, not the native one)."""
        layers = self.scene.view_layers
        vl = layers.get(object_coords.COORDS_LAYER)
        if vl is not None and vl != self.view_layer and len(layers) > 1:
            layers.remove(vl)
        self.coords_layer = None

    # -- once per render --------------------------------------------------------------------------
    def render(self, render_dir: str | os.PathLike, seed: int) -> RenderOutput:
        """Render the current camera pose with Cycles seed `seed`; write the requested files into
        `render_dir` (created if missing) and return them with their arrays."""
        if self.tree is None:
            raise DataPipeError("Renderer.setup() must run before render()")
        render_dir = Path(render_dir)
        make_dirs(render_dir)          # never through a link in the output folder
        for stale in compat.written_files(render_dir, TEMP_BASENAME):
            stale.unlink()
        try:
            compat.set_file_output_path(self.file_output, render_dir, TEMP_BASENAME)
        except ValueError as e:
            raise DataPipeError(f"output folder {render_dir}: {e} (fix: choose an output folder "
                                "whose path has no '{' or '}')") from None
        self.scene.cycles.seed = int(seed) & 0x7FFFFFFF
        T_world_cam = self.camera.T_world_cam()
        if "object_coords" in self.outputs:        # the materials of this scene's parts
            coll = bpy.data.collections.get(OBJECTS_COLLECTION)
            object_coords.prepare_parts(coll.all_objects if coll is not None else [])

        t0 = time.perf_counter()
        res = self.scene.render
        with self.progress.cycles("render", f"{', '.join(self.cfg.render.outputs)} at {res.resolution_x} x "
                                       f"{res.resolution_y}, {self.scene.cycles.samples} samples"):
            # render.sampling_pattern is the native render's: the fringe calls keep the scene's own
            # (blue noise moved the fringe decode's valid share beyond its seed spread: fringe_settings.md)
            with compat.sampling_pattern(self.scene.cycles, self.cfg.render.sampling_pattern):
                bpy.ops.render.render(write_still=False, scene=self.scene.name)
        seconds = time.perf_counter() - t0
        self.progress.begin("write", "native files")

        channels = compat.take_written_exr(render_dir, TEMP_BASENAME, "pass", expect=[
            f"{item}.{c}" for item, (_, _, socket_type) in self._items.items() for c in _CHANNELS[socket_type]])
        grid = getattr(self.camera, "lens", None)
        if grid is not None:      # render grid -> the camera's image (datapipe/lens.py): radiance by spline,
            channels = {k: grid.remap(v, linear=k.startswith("Image.")) for k, v in channels.items()}  # maps nearest
        out = self._convert(channels, T_world_cam)
        out.seconds = seconds
        out.T_world_cam = T_world_cam
        out.files = self._write(render_dir, out)
        return out

    def _layer(self, channels: dict, item: str) -> np.ndarray:
        socket_type = self._items[item][2]
        names = _CHANNELS[socket_type]
        try:
            arrs = [channels[f"{item}.{c}"] for c in names]
        except KeyError:
            raise DataPipeError(f"the pass file lacks layer {item!r} (channels: {sorted(channels)})") from None
        if socket_type == "FLOAT":
            return arrs[0]
        if socket_type == "RGBA":
            arrs = arrs[:3]
        return np.stack(arrs, axis=-1)

    def _convert(self, channels: dict, T_world_cam: np.ndarray) -> RenderOutput:
        out = RenderOutput(files={})
        if "rgb" in self.outputs:
            out.rgb = linear_to_srgb8(self._layer(channels, "Image"))
        if "depth" in self.outputs:
            z = self._layer(channels, "Depth").astype(np.float32)
            z[~(np.isfinite(z) & (z < NO_HIT_DEPTH) & (z > 0))] = np.nan
            out.depth = z
        if "mask" in self.outputs:
            out.mask = np.rint(self._layer(channels, "IndexOB")).astype(np.int32)
        if "object_coords" in self.outputs:
            hit = self._layer(channels, "ObjectHit") == 1.0        # one sample: exactly 1 on a part
            xyz = self._layer(channels, "ObjectXYZ").astype(np.float32)
            xyz[~hit] = np.nan
            out.object_coords = xyz
        if "normals" in self.outputs:
            n_world = self._layer(channels, "Normal").astype(np.float64)
            n_cam = n_world @ T_world_cam[:3, :3]              # R_wc^T n, row-vector form
            norm = np.linalg.norm(n_cam, axis=-1, keepdims=True)
            hit = norm > 1e-6
            out.normals = np.where(hit, n_cam / np.where(hit, norm, 1.0), 0.0).astype(np.float32)
        return out

    def _write(self, render_dir: Path, out: RenderOutput) -> dict[str, Path]:
        maps = {}
        if out.rgb is not None:
            maps["rgb"] = np.ascontiguousarray(out.rgb[..., ::-1])        # cv2 writes BGR
        if out.depth is not None:
            maps["depth"] = {"Z": out.depth}
        if out.normals is not None:
            maps["normals"] = {c: out.normals[..., i] for i, c in enumerate("XYZ")}
        if out.mask is not None:
            maps["mask"] = {"Y": out.mask.astype(np.float32)}
        if out.object_coords is not None:
            maps["object_coords"] = {c: out.object_coords[..., i] for i, c in enumerate("XYZ")}
        return write_render_maps(render_dir, maps)
