"""The structured-light camera inside the pipeline: projector + fringe view layers at setup, then per
render: fringe render (here) -> `sl.Scanner` (sensor model -> decode -> filters, pure numpy) ->
sl_depth.exr / sl_valid.png (+ sl_debug.exr). Defaults and their measurements:
benchmarks/results/sl_render.md.

Only built when `cfg.structured_light.enabled`; with it off, none of this exists in the scene.

Fringe render (its own Cycles call): one strategy per fringe mode
-----------------------------------------------------------------
What the camera does is decided once per run in a `FringePlan` (config/plan.py: the mode "auto"
resolves to, the variant, the images, the Cycles calls, the unwrap plan, the samples), and
`make_strategy` builds the mode's strategy from it, which the camera holds (`strategy`):
`structured_light.fringe_mode` "render" path-traces every pattern as described here (the
reference; `RenderFringes`, core/fringe_render.py); "quadrature" path-traces, the same way and in
the same call, a white image and a cos and a sin image per period instead (1 + 2F images instead
of F x N, + 2 instead of N for the row code) and mixes every phase step from them (sl/fringe_basis.py:
light is linear in the projected image; one seed, so the render mode's very paths: the same frames
up to float rounding, mirror images included; `QuadratureFringes`, core/fringe_quadrature.py).
Where every configured material is grey (`grey_materials`) the images travel three to a light,
one per colour channel (the plan's `packed`: the white layer, then 3 images per layer; 4 layers
instead of 9 with the default periods and the row code, sl.pack_basis); a layer costs its paths
whatever it emits, so the fringe call costs ~4/9 of the unpacked one
(benchmarks/results/sl_glossy_modes.md). "fast" renders once with the projector showing white and
synthesises every pattern's direct light from it (`FastFringes`, core/fringe_fast.py,
sl/fringe_synth.py), on the same point-sample grid. Tests and benchmarks choose a variant `auto`
never picks by `FringePlan.from_config`'s arguments (packed, coarse_supersample, bounce_min_gain).

The fringe view layers (`sl_00` ...) are rendered in a second `render.render` call right after the
Renderer's native one, with the native layer switched off and the Renderer's File Output node muted;
a File Output node of our own writes the fringe layers into `_sl_fringes.exr` (read back, deleted).
What differs from the native call (all restored afterwards):

- Pixel sampling: the fringes are rendered at FRINGE_SUPERSAMPLE (2) x the camera resolution with
  a point-like pixel filter (FRINGE_FILTER_WIDTH = 0.01 px) and averaged over 2x2 blocks, i.e. the
  exact pixel-area average at four points symmetric about the pixel centre. With Cycles' default
  1.5 px Blackman-Harris filter every pixel is the mean of a few jittered sub-pixel samples whose
  positions are the same in all fringe layers (one seed), so the decoded phase is that of their
  centroid, not of the pixel centre: 9x the sensor-noise limit at 4 samples, 2-3x at 16 (plane,
  320x240). `samples` counts paths per camera pixel (samples / 4 per sub-pixel, at least 1). The
  native RGB keeps its own filter because it is rendered in its own call.
- Seed: the render seed (as for the native layer): the shifted frames see the same Monte-Carlo
  paths, so render noise common to all steps cancels in the phase.

Ambient light (`structured_light.ambient` "scene")
--------------------------------------------------
The fringe layers see the projector alone (scene lights excluded, black world). With "scene" one
more layer, the projector-off layer (projector.AMBIENT_LAYER: every projector light excluded, the
scene's lights and world kept), is rendered in the same call at the same grid (`ambient_image`),
and `process` hands it to the scanner, which adds it to every frame before exposure and sensor and
keeps a projector-off capture for the global-light filter (light is linear: exact, one layer's
paths; docs/STRUCTURED_LIGHT.md). With "off" the layer is never made.

Inter-reflected light (projector node tree, `regularize_indirect`)
-------------------------------------------------------------------
Light that reaches a surface on a path with a *diffuse* bounce between it and the camera (Light
Path "Diffuse Depth" > 0 in the light's shader) sees the pattern blurred by INDIRECT_BLUR_PX
projector pixels. With a few paths per pixel the diffusely inter-reflected part of a fine fringe
is otherwise Monte-Carlo noise (each path picks up the pattern at one random point of another
surface): 3x the noise limit on the bin floor at 4 samples. Physically a diffuse bounce averages
the fine pattern over a footprint of many periods (why fine fringes resist inter-reflections), so
the blur is the expected value, computed analytically (a blurred sinusoid is the sinusoid with
less modulation): the 64-period fringe keeps ~0 of its modulation after a diffuse bounce (its
light still raises the offset and lowers the contrast), the 8-period 21%, the 1-period 98%, so
the coarse patterns keep their real inter-reflection bias. Glossy bounces: a mirror image of a
fringe is a fringe, with the phase of the mirrored surface -- the ghost points and holes of real
scanners on shiny parts. When the scene has a shiny surface (a visible material with roughness
below SHINY_ROUGHNESS = 0.45: steel, aluminium, painted, dark plastic presets; checked per render,
`has_shiny_surface`), paths whose bounces are all glossy (Light Path Glossy Depth, not counted)
see the SHARP pattern and Monte Carlo over the lobe blurs it as much as the roughness does
(tests/blender/test_sl_glossy.py). Otherwise glossy bounces are blurred like diffuse ones: a
rough lobe (the bin's 0.6) averages the fine fringe over centimetres, and Monte Carlo at 4 paths
per pixel would turn it into noise (p99 error on the demo bin 0.6 -> 1.0 mm measured). The
light shader cannot see the roughness of the surface a path bounced off, hence the per-scene
switch. Direct light is unchanged (tested byte-for-byte).

Sensor, decode and filters
--------------------------
`sl.Scanner` (datapipe/sl/scanner.py): exposure (fixed, auto, HDR: sl.exposure), the seeded
sensor model, the decoder, the local reflection (multipath) filter (reason MULTIPATH = 8), the
global reflection filter (reason REFLECTION = 10), the projector-border and edge/speckle filters
(reason FILTERED = 7), and the maps written per render. This module only renders the fringes,
and for the global reflection filter a row code (8 periods of row fringes, `steps` images, built
as more pattern lights and view layers in render mode, a cos and a sin one in quadrature mode)
on the renders that need it:
`structured_light.reflection_filter` "global", or "auto" when the render has sharp glossy fringes
(a shiny surface: the only renders that can show mirror ghosts). Its view layers are left out of
the Cycles call on the other renders, so they cost nothing there.

Timing: `last_seconds` holds the fringe call's and the scan's wall time of the last render (the
pipeline reports both as its "structured_light" stage); they are kept out of the annotations so
two runs of one seed write identical scene.json files.
"""
from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from .. import sl
from ..config.plan import FRINGE_SUPERSAMPLE, FringePlan, layer_samples  # noqa: F401 (FRINGE_SUPERSAMPLE: benchmarks)
from ..config.plan import SHINY_ROUGHNESS, grey_materials, resolve_fringe_mode  # noqa: F401 (the camera's rules)
from ..geometry import T_cam_proj, projector_intrinsics
from ..io import layout
from ..io.native import write_render_maps
from . import projector as _pj
from .fringe_call import INDIRECT_BLUR_PX, indirect_gain  # noqa: F401 (the bounce blur, for benchmarks)
from .fringe_fast import FastFringes
from .fringe_quadrature import QuadratureFringes
from .fringe_render import FRINGE_BASENAME, OUTPUT_NODE, RenderFringes  # noqa: F401 (the fringe call's names)

FRINGE_FILTER_WIDTH = 0.01      # px, Blackman-Harris pixel filter of the fringe render (point samples)


class FringeStrategy(Protocol):
    """One fringe mode's Blender side, held by the StructuredLightCamera (built from its FringePlan):
    RenderFringes (core/fringe_render.py), QuadratureFringes (core/fringe_quadrature.py), FastFringes
    (core/fringe_fast.py). Each reads the camera it is given for the config, the scene, the plan
    and the render settings."""
    layer_names: list[str]          # the view layers it made
    file_output: object             # the File Output node its fringe call writes through

    def setup(self) -> None: ...

    def render(self, render_dir, seed: int, T_world_cam, rows: bool) -> tuple[np.ndarray, float, np.ndarray | None]:
        """-> ((F*N [+ the row code's N with `rows`], H, W) float32 radiance, wall seconds, the
        projector-off layer's (H, W) image of the same call or None)."""

    def set_samples(self, layer_samples: int) -> None: ...

    def set_sharp_glossy(self, sharp: bool) -> None: ...

    def set_indirect_blur(self, blur_px: float) -> None: ...

    def glossy_fringes(self, sharp: bool) -> str: ...

    def teardown(self) -> None: ...


def make_strategy(cam) -> FringeStrategy:
    """The strategy of the camera's plan: its mode, its variant as constructor arguments."""
    plan = cam.plan
    if plan.mode == "fast":
        return FastFringes(cam, bounce_min_gain=plan.bounce_min_gain)
    if plan.mode == "quadrature":
        return QuadratureFringes(cam, packed=plan.packed, calls=plan.quad_calls())
    return RenderFringes(cam)


class StructuredLightCamera:
    """Projector + fringe layers (setup), and per render: fringes -> depth (process). What it does
    is decided once per run in its FringePlan (config/plan.py; `plan`, by default the config's):
    the fringe mode's strategy (`strategy`) renders, this class scans and writes.

    >>> slc = StructuredLightCamera(cfg, bpy_scene, camera, renderer); slc.setup()
    >>> files, info = slc.process(render_dir, seed, T_world_cam)           # after renderer.render
    >>> stack, seconds = slc.render_fringes(render_dir, seed)               # the pieces, for benchmarks
    >>> scan = slc.scanner.scan(stack, seed, camera.K, T_world_cam)         # sl.Scanner
    >>> plan = FringePlan.from_config(cfg, packed=False)                    # a variant auto never picks
    >>> slc = StructuredLightCamera(cfg, bpy_scene, camera, renderer, plan)
    """

    def __init__(self, cfg, bpy_scene, camera, renderer, plan: FringePlan | None = None):
        self.cfg, self.scene, self.camera, self.renderer = cfg, bpy_scene, camera, renderer
        self.plan = FringePlan.from_config(cfg) if plan is None else plan
        self.proj_size = tuple(int(v) for v in cfg.projector.resolution)
        self.scanner = sl.Scanner.from_config(cfg, unwrap=self.plan.unwrap)   # the plan's: decoded per render
        # render settings (benchmarks vary them between renders without rebuilding)
        self.filter_width = FRINGE_FILTER_WIDTH
        self.supersample = self.plan.supersample    # quadrature's calls keep the plan's grids
        self.indirect_blur_px = INDIRECT_BLUR_PX
        self.samples = self.plan.samples
        self.sharp_glossy = False
        self.ambient_image = None               # the projector-off layer's (H, W) float32 radiance, last fringe call
        self.strategy = make_strategy(self)
        self.last_seconds: dict = {}     # {"render": s, "decode": s} of the last process() (not annotated:
                                         # annotations stay identical between runs of one seed)

    # -- once per run -----------------------------------------------------------------------------
    def setup(self) -> None:
        remove_leftovers(self.scene, self.renderer.tree)
        self.strategy.setup()

    def set_indirect_blur(self, blur_px: float) -> None:
        """Blur (projector px) of the pattern seen by inter-reflected light; 0 = none (benchmarks)."""
        self.indirect_blur_px = float(blur_px)
        self.strategy.set_indirect_blur(self.indirect_blur_px)

    def wants_rows(self) -> bool:
        """Whether this render needs the row code: reflection_filter "global", or "auto" with sharp
        glossy fringes (a shiny surface in the scene: the only renders that can show mirror ghosts)."""
        return self.plan.row_code and (self.plan.reflection_filter == "global" or self.sharp_glossy)

    def set_sharp_glossy(self, sharp: bool) -> None:
        """Glossy bounces see the sharp pattern (True) or the blurred one like diffuse bounces."""
        self.sharp_glossy = bool(sharp)
        self.strategy.set_sharp_glossy(self.sharp_glossy)

    @property
    def layer_samples(self) -> int:
        """Cycles samples per (supersampled) pixel of the fringe layers: `samples` is per camera pixel."""
        return layer_samples(self.samples, self.supersample)

    def set_samples(self, samples: int) -> None:
        """Paths per camera pixel of every fringe layer (benchmarks vary it without rebuilding)."""
        self.samples = int(samples)
        self.strategy.set_samples(self.layer_samples)

    # -- once per render --------------------------------------------------------------------------
    def render_fringes(self, render_dir, seed: int, T_world_cam=None, rows: bool | None = None
                       ) -> tuple[np.ndarray, float]:
        """Render the fringes (own Cycles call, see the module doc) -> ((F*N, H, W) float32 linear
        radiance, frequency-major, followed by the row code's N images when `rows` (default
        `wants_rows()`); wall seconds of the call, and in fast mode of the synthesis). `T_world_cam`
        (fast mode: the pose P_proj is made from) defaults to the camera's current pose.
        With ambient "scene" the same call renders the projector-off layer too: `ambient_image`,
        (H, W) float32 at the same grid, what the scanner adds to every frame (`process`)."""
        self.ambient_image = None
        stack, seconds, self.ambient_image = self.strategy.render(
            render_dir, seed, T_world_cam, self.wants_rows() if rows is None else bool(rows))
        return stack, seconds

    def process(self, rdir: Path, seed: int, T_world_cam) -> tuple[dict[str, Path], dict]:
        """Render the fringes, scan them, write the maps; returns ({kind: written file}, the render's
        structured_light record for scene.json)."""
        s, plan = self.cfg.structured_light, self.plan
        rdir = Path(rdir)
        self.set_sharp_glossy(has_shiny_surface(self.scene))
        radiance, render_s = self.render_fringes(rdir, seed, T_world_cam)
        grid = getattr(self.camera, "lens", None)
        if grid is not None:            # render grid -> the camera's image, radiance by spline (datapipe/lens.py)
            radiance = grid.remap(radiance, linear=True)
        self.renderer.progress.begin("decode", f"{radiance.shape[0]} images, exposure {s.exposure}, HDR {s.hdr or 'off'}")
        scan = self.scanner.scan(radiance, seed, self.camera.K, T_world_cam, ambient=self.ambient_image)
        self.last_seconds = {"render": render_s, "decode": scan.seconds}
        self.renderer.progress.begin("maps")
        files = write_render_maps(rdir, scan.maps(debug=s.debug))
        files.update(self._write_scanner_outputs(rdir, scan))
        summary = scan.summary()
        extra = {} if self.ambient_image is None else {      # "off" keeps today's record, key for key
            "ambient": "scene", "ambient_to_projector": summary["ambient_to_projector"]}
        return files, {**extra,
            "periods": list(plan.periods), "steps": plan.steps, "unwrap": summary["unwrap"], "samples": plan.samples,
            "fringe_mode": plan.mode, "sensor": s.sensor, "exposure": summary["exposure"],
            "exposure_mode": summary["exposure_mode"], "hdr": summary["hdr"],
            "reflection_filter": summary["reflection_filter"],
            "glossy_fringes": self.strategy.glossy_fringes(self.sharp_glossy),
            "power": float(self.cfg.projector.power),
            "filter_width": float(self.filter_width), "P_proj": scan.P_proj,
            "K_proj": projector_intrinsics(self.cfg),
            "T_cam_proj": T_cam_proj(self.cfg), "proj_resolution": list(self.proj_size),
            "valid_fraction": summary["valid_fraction"], "reasons": summary["reasons"],
            "median_sigma_z": summary["median_sigma_z"],
        }

    def _write_scanner_outputs(self, rdir: Path, scan) -> dict[str, Path]:
        """The scanner's grey image and organised point cloud, each only when render.outputs lists it
        (a run without them computes and writes nothing of them)."""
        wanted = [k for k in ("sl_gray", "point_cloud") if k in self.cfg.render.outputs]
        if not wanted:
            return {}
        from ..io.point_cloud import write_point_cloud
        gray = scan.gray()
        files = {}
        if "sl_gray" in wanted:
            files.update(write_render_maps(rdir, {"sl_gray": gray}))
        if "point_cloud" in wanted:
            path = rdir / layout.RENDER_FILES["point_cloud"]
            grid = getattr(self.camera, "lens", None)     # a distorting lens: each pixel's undistorted ray
            rays = grid.ideal_normalised() if grid is not None and grid.d is not None else None
            write_point_cloud(path, scan.result.depth, self.camera.K, gray, scan.result.confidence, rays)
            files["point_cloud"] = path
        return files

    def teardown(self) -> None:
        """Remove everything setup() built (lights, layers, compositor nodes)."""
        self.strategy.teardown()


def has_shiny_surface(bpy_scene) -> bool:
    """Whether any rendered mesh in the scene has a glossy lobe narrower than SHINY_ROUGHNESS
    (Principled / Glossy / Anisotropic BSDF roughness; core/materials records the value of the
    materials it builds, whose roughness socket may be driven by a texture)."""
    for ob in bpy_scene.objects:
        if ob.type != "MESH" or ob.hide_render:
            continue
        for slot in ob.material_slots:
            mat = slot.material
            if mat is None or mat.node_tree is None:
                continue
            if "datapipe_roughness" in mat:
                if float(mat["datapipe_roughness"]) < SHINY_ROUGHNESS:
                    return True
                continue
            for n in mat.node_tree.nodes:
                r = n.inputs.get("Roughness") if n.type in ("BSDF_PRINCIPLED", "BSDF_GLOSSY", "BSDF_ANISOTROPIC") \
                    else None
                if r is not None and not r.is_linked and float(r.default_value) < SHINY_ROUGHNESS:
                    return True
    return False


def remove_leftovers(bpy_scene, tree=None) -> None:
    """Delete the projector lights, pattern images, collections, fringe view layers and compositor
    nodes an earlier run left in this Blender session or saved into the .blend (the pipeline
    builds them once per run and does not tear them down), so a new run starts clean."""
    import re

    import bpy

    layer_re = re.compile(re.escape(_pj.LAYER_PREFIX) + r"\d\d$")
    for vl in list(bpy_scene.view_layers):
        if (layer_re.match(vl.name) or vl.name == _pj.AMBIENT_LAYER) and len(bpy_scene.view_layers) > 1:
            bpy_scene.view_layers.remove(vl)
    for ob in list(bpy.data.objects):
        if ob.name.startswith(_pj.LIGHT_PREFIX) and ob.type == "LIGHT":
            ld = ob.data
            bpy.data.objects.remove(ob, do_unlink=True)
            if ld is not None and ld.users == 0:
                bpy.data.lights.remove(ld)
    for ld in list(bpy.data.lights):
        if ld.name.startswith(_pj.LIGHT_PREFIX) and ld.users == 0:
            bpy.data.lights.remove(ld)
    for img in list(bpy.data.images):
        if img.name.startswith(_pj.IMAGE_PREFIX):
            bpy.data.images.remove(img)
    for coll in list(bpy.data.collections):
        if coll.name.startswith(_pj.COLLECTION_PREFIX) and not coll.all_objects:
            bpy.data.collections.remove(coll)
    if tree is not None:
        for n in list(tree.nodes):
            if n.name.startswith(OUTPUT_NODE):
                tree.nodes.remove(n)
