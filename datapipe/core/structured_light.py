"""The structured-light camera inside the pipeline: projector + fringe view layers at setup, then per
render: fringe render (here) -> `sl.Scanner` (sensor model -> decode -> filters, pure numpy) ->
sl_depth.exr / sl_valid.png (+ sl_debug.exr). Defaults and their measurements:
benchmarks/results/sl_render.md.

Only built when `cfg.structured_light.enabled`; with it off, none of this exists in the scene.

Fringe render (its own Cycles call)
-----------------------------------
`structured_light.fringe_mode` "render" path-traces every pattern as described here (the
reference); "quadrature" path-traces, the same way and in the same call, a white image and a
cos and a sin image per period instead (1 + 2F images instead of F x N, + 2 instead of N for the
row code) and mixes every phase step from them (sl/fringe_basis.py: light is linear in the
projected image; one seed, so the render mode's very paths: the same frames up to float
rounding, mirror images included; `quad_groups`, `_light_gains`). Where every configured
material is grey (`grey_materials`) the images travel three to a light, one per colour channel
(`pack_channels`: the white layer, then 3 images per layer; 4 layers instead of 9 with the
default periods and the row code, sl.pack_basis); a layer costs its paths whatever it emits, so
the fringe call costs ~4/9 of the unpacked one (benchmarks/results/sl_glossy_modes.md). "fast" renders once with the
projector showing white and synthesises every pattern's direct light from it
(core/fringe_fast.py, sl/fringe_synth.py), on the same point-sample grid.

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

import time
from pathlib import Path

import numpy as np

from .. import sl
from ..config.plan import FRINGE_SUPERSAMPLE, builds_row_code   # FRINGE_SUPERSAMPLE: the memory check counts it
from ..config.plan import SHINY_ROUGHNESS, grey_materials, resolve_fringe_mode  # noqa: F401 (the camera's rules)
from ..geometry import T_cam_proj, projector_intrinsics, projector_matrix
from ..io import layout
from ..io.native import write_render_maps
from . import projector as _pj
from .fringe_call import INDIRECT_BLUR_PX, block_mean, indirect_gain, isolated_render, link_ambient_layer
from .projector import AMBIENT_LAYER, LIGHTS_COLLECTION, Projector

FRINGE_FILTER_WIDTH = 0.01      # px, Blackman-Harris pixel filter of the fringe render (point samples)
FRINGE_BASENAME = "_sl_fringes"  # the fringe call's multilayer EXR in the render folder (deleted)
OUTPUT_NODE = "datapipe_sl_file_output"
INDIRECT_NODE = "datapipe_sl_indirect_blur"
GLOSSY_NODE = "datapipe_sl_glossy_switch"
GREY_SUFFIX = "_grey"            # a packed white layer's grey value, written beside its R, G, B
QUAD_COARSE_SUPERSAMPLE = 2      # quadrature mode: = FRINGE_SUPERSAMPLE: one call, render mode's paths; 1: the
                                 # coarse periods at the camera grid in a second call (quad_groups)
QUAD_PACK_CHANNELS = True        # quadrature mode: three basis images per layer, one per colour channel
                                 # (sl.pack_basis; False: one per layer, for benchmarks/results/sl_glossy_modes.md)


class StructuredLightCamera:
    """Projector + fringe layers (setup), and per render: fringes -> depth (process).

    >>> slc = StructuredLightCamera(cfg, bpy_scene, camera, renderer); slc.setup()
    >>> files, info = slc.process(render_dir, seed, T_world_cam)           # after renderer.render
    >>> stack, seconds = slc.render_fringes(render_dir, seed)               # the pieces, for benchmarks
    >>> scan = slc.scanner.scan(stack, seed, camera.K, T_world_cam)         # sl.Scanner
    """

    def __init__(self, cfg, bpy_scene, camera, renderer):
        self.cfg, self.scene, self.camera, self.renderer = cfg, bpy_scene, camera, renderer
        s = cfg.structured_light
        self.periods, self.steps = list(s.periods), int(s.steps)
        self.proj_size = tuple(int(v) for v in cfg.projector.resolution)
        self.scanner = sl.Scanner.from_config(cfg)   # refuses an ambiguous period set before any render
        self.filter_width = FRINGE_FILTER_WIDTH
        self.supersample = FRINGE_SUPERSAMPLE
        self.coarse_supersample = QUAD_COARSE_SUPERSAMPLE   # quadrature mode: the coarse periods' grid
        self.pack_channels = QUAD_PACK_CHANNELS and grey_materials(cfg)   # quadrature: an image per colour channel
        self.indirect_blur_px = INDIRECT_BLUR_PX
        self.sharp_glossy = False
        self.samples = int(s.samples)
        self.fringe_mode = resolve_fringe_mode(cfg)   # "fast": one flat-lit call (core/fringe_fast.py); "render"
        self.flat = None                       # FlatLitRender in fast mode
        self.bounce_min_gain = None            # fast mode: periods with bounce layers (None: its default)
        self._profiles = sl.pattern_profiles(self.proj_size[0], self.periods, self.steps)
        self.reflection_filter = s.reflection_filter
        self.row_code = builds_row_code(s, self.fringe_mode)
        self.ambient = s.ambient == "scene"     # the projector-off layer, added to every frame (module doc)
        self.ambient_image = None               # its (H, W) float32 radiance from the last fringe call
        self.layers: list = []
        self.layer_names: list[str] = []      # the fringe layers, then the row code's (when `row_code`)
        self.file_output = None
        self._rl_nodes: list = []
        self.last_seconds: dict = {}     # {"render": s, "decode": s} of the last process() (not annotated:
                                         # annotations stay identical between runs of one seed)

    # -- once per run -----------------------------------------------------------------------------
    def setup(self) -> None:
        import bpy
        from . import compat

        remove_leftovers(self.scene, self.renderer.tree)
        if self.fringe_mode == "fast":
            from .fringe_fast import FlatLitRender
            kw = {} if self.bounce_min_gain is None else {"min_gain": self.bounce_min_gain}
            self.flat = FlatLitRender(self.cfg, self.scene, self.camera, self.renderer, **kw)
            self.flat.setup()
            self.set_samples(self.samples)
            return
        Wp, Hp = self.proj_size
        gamma = self.cfg.structured_light.projector_gamma
        if self.fringe_mode == "quadrature":     # white + (cos, sin) per frequency: sl/fringe_basis.py
            if gamma != 1.0:
                raise ValueError("fringe_mode 'quadrature' needs a linear projector (projector_gamma 1)")
            patterns = [sl.quadrature_basis(Wp, Hp, per, row_periods=rows) for per, rows, _ in self.quad_groups()]
            if self.pack_channels:
                patterns = [sl.pack_basis(b, self._layout(per, rows))
                            for b, (per, rows, _) in zip(patterns, self.quad_groups())]
            patterns = np.concatenate(patterns)
        else:
            patterns = sl.fringe_patterns(Wp, Hp, self.periods, self.steps, gamma=gamma)
            if self.row_code:              # the global reflection filter's row code (sl.Scanner.scan)
                patterns = np.concatenate([patterns, self.scanner.row_patterns(gamma)])
        self.projector = Projector(self.cfg, self.scene, self.camera.obj)
        self.projector.build(patterns)
        for ob, (gain, offset) in zip(self.projector.lights, self._light_gains()):
            regularize_indirect(ob.data.node_tree, gain, offset)
        self.layers = self.projector.make_view_layers(exclude=[LIGHTS_COLLECTION])
        self.layer_names = [vl.name for vl in self.layers]
        tree = self.renderer.tree
        self.file_output = compat.new_file_output(tree, bpy.app.tempdir or "/tmp", FRINGE_BASENAME,
                                                  name=OUTPUT_NODE)
        if self.ambient:
            self._rl_nodes.append(link_ambient_layer(self.projector, tree, self.scene, self.file_output,
                                                     f"{OUTPUT_NODE}_rl_ambient", self.layer_samples))
        packed = self.fringe_mode == "quadrature" and self.pack_channels
        whites = set(self._white_layers()) if packed else set()
        for i, vl in enumerate(self.layers):
            vl.use = False                   # rendered only by render_fringes(), not by the native call
            rl = compat.render_layers_node(tree, self.scene, vl.name, name=f"{OUTPUT_NODE}_rl_{i:02d}")
            rl.location = (-700, -300 * i)
            image = compat.rl_socket(rl, "image")
            # a grey layer is written as the compositor's grey value (its luminance), the frame a
            # monochrome camera takes; a packed one as R, G, B, and its white layer also as grey
            tree.links.new(image, compat.file_output_add_input(self.file_output, vl.name,
                                                               "RGBA" if packed else "FLOAT"))
            if i in whites:
                tree.links.new(image, compat.file_output_add_input(self.file_output, vl.name + GREY_SUFFIX, "FLOAT"))
            self._rl_nodes.append(rl)
        self.file_output.format.exr_codec = "NONE"     # a scratch file: no time spent compressing
        self.file_output.mute = True
        self.set_samples(self.samples)

    def set_indirect_blur(self, blur_px: float) -> None:
        """Blur (projector px) of the pattern seen by inter-reflected light; 0 = none (benchmarks)."""
        self.indirect_blur_px = float(blur_px)
        if self.flat is not None:            # fast mode: bounced light is offset only, nothing to blur
            return
        for ob, (gain, offset) in zip(self.projector.lights, self._light_gains()):
            _set_gain(ob.data.node_tree.nodes[INDIRECT_NODE], gain, offset)

    def quad_groups(self) -> list[tuple[tuple, tuple, int]]:
        """Quadrature mode's Cycles calls: (periods, row periods, supersample) each, one white image
        + a (cos, sin) pair per period in each. All in one call on the render mode's 2x2 point grid
        when `coarse_supersample` equals `supersample` (the shipped default: the same paths as
        render mode, so the same frames, float rounding aside); else the finest period (the depth)
        and the row code (the reflection filter) there, and the coarse periods (fringe orders only)
        in a second call at `coarse_supersample` (1: one path per camera pixel at its centre, a
        quarter of the paths; measured in benchmarks/results/sl_glossy_modes.md)."""
        rows = tuple(sl.scanner.ROW_PERIODS) if self.row_code else ()
        if int(self.coarse_supersample) == int(self.supersample) or len(self.periods) == 1:
            return [(tuple(self.periods), rows, int(self.supersample))]
        fine = max(self.periods)
        return [((fine,), rows, int(self.supersample)),
                (tuple(K for K in self.periods if K != fine), (), int(self.coarse_supersample))]

    @staticmethod
    def _layout(per, rows) -> list[tuple]:
        """A quadrature call's packed layers (sl.packed_layout): the basis image in each channel."""
        return sl.packed_layout(len(per), len(rows))

    def _white_layers(self) -> list[int]:
        """Indices (in `layers`) of each quadrature call's white layer, the first of its layers."""
        out, i = [], 0
        for per, rows, _ in self.quad_groups():
            out.append(i)
            i += len(self._layout(per, rows)) if self.pack_channels else sl.basis_size(len(per), rows=bool(rows))
        return out

    def _light_gains(self) -> list[tuple[float, float]]:
        """(modulation a bounce keeps, the image's mean) of each pattern light (`regularize_indirect`):
        the fringes across the width, then the row code's over the height. Quadrature mode, per
        call (`quad_groups`): the white image, then a (cos, sin) pair per frequency. A white image
        is shared by frequencies whose bounce gains differ: it gets gain 0 (its bounce light is
        `alpha`, the image's mean times its opacity), what the mixed frames need wherever the image
        is opaque (sl/fringe_basis.py), and the finest fringe (gain ~0: the depth) matches the render
        mode's also in the image's faded outer half texel, where the coarse ones differ by gain x
        the fade (up to 1% of the peak on 6 of 4800 pixels of a mirror scene, measured)."""
        Wp, Hp = self.proj_size
        g = lambda K, length: indirect_gain(K, length, self.indirect_blur_px)  # noqa: E731
        if self.fringe_mode == "quadrature":
            out = []
            for per, rows, _ in self.quad_groups():
                images = [(0.0, 1.0)] + [(g(K, Wp), 0.5) for K in per for _ in range(2)]
                images += [(g(K, Hp), 0.5) for K in rows for _ in range(2)]
                if not self.pack_channels:
                    out += images
                    continue
                for chans in self._layout(per, rows):      # per channel; an unused one emits nothing
                    pairs = [images[j] if j is not None else (0.0, 0.0) for j in chans]
                    out.append((tuple(p[0] for p in pairs), tuple(p[1] for p in pairs)))
            return out
        out = [(g(K, Wp), 0.5) for K in self.periods for _ in range(self.steps)]
        if self.row_code:
            out += [(g(K, Hp), 0.5) for K in sl.scanner.ROW_PERIODS for _ in range(self.steps)]
        return out

    def wants_rows(self) -> bool:
        """Whether this render needs the row code: reflection_filter "global", or "auto" with sharp
        glossy fringes (a shiny surface in the scene: the only renders that can show mirror ghosts)."""
        return self.row_code and (self.reflection_filter == "global" or self.sharp_glossy)

    def set_sharp_glossy(self, sharp: bool) -> None:
        """Glossy bounces see the sharp pattern (True) or the blurred one like diffuse bounces."""
        self.sharp_glossy = bool(sharp)
        if self.flat is not None:    # fast mode: every bounce of the fine fringe is offset only
            return
        for ob in self.projector.lights:
            ob.data.node_tree.nodes[GLOSSY_NODE].inputs[1].default_value = 0.0 if sharp else 1.0

    @property
    def layer_samples(self) -> int:
        """Cycles samples per (supersampled) pixel of the fringe layers: `samples` is per camera pixel."""
        return max(1, int(np.ceil(self.samples / self.supersample ** 2)))

    def set_samples(self, samples: int) -> None:
        """Paths per camera pixel of every fringe layer (benchmarks vary it without rebuilding)."""
        self.samples = int(samples)
        for vl in self.layers:
            vl.samples = self.layer_samples
        if self.ambient and self.flat is None:
            self.scene.view_layers[AMBIENT_LAYER].samples = self.layer_samples

    # -- once per render --------------------------------------------------------------------------
    def render_fringes(self, render_dir, seed: int, T_world_cam=None, rows: bool | None = None
                       ) -> tuple[np.ndarray, float]:
        """Render the fringe layers (own Cycles call, see the module doc) -> ((F*N, H, W) float32
        linear radiance, frequency-major, followed by the row code's N images when `rows` (default
        `wants_rows()`); wall seconds of the call, and in fast mode of the synthesis). `T_world_cam`
        (fast mode: the pose P_proj is made from) defaults to the camera's current pose.
        With `ambient` the same call renders the projector-off layer too: `ambient_image`, (H, W)
        float32 at the same grid, what the scanner adds to every frame (`process`)."""
        ss = int(self.supersample)
        self.ambient_image = None
        if self.flat is not None:
            if T_world_cam is None:
                T_world_cam = self.camera.T_world_cam()
            lit, seconds = self.flat.render(render_dir, seed, supersample=ss, filter_width=self.filter_width,
                                            samples=self.layer_samples)
            t0 = time.perf_counter()
            if lit.ambient is not None:
                self.ambient_image = block_mean(lit.ambient[None], ss)[0]
            stack = sl.synthesize_fringes(lit.direct, lit.indirect, lit.points,
                                          projector_matrix(self.cfg, T_world_cam), self._profiles, block=ss)
            bounce = lit.bounce(self.periods, self.steps, ss)
            if bounce is not None:
                stack += bounce
            return stack, seconds + time.perf_counter() - t0
        if rows is None:
            rows = self.wants_rows()
        if rows and not self.row_code:
            raise ValueError("render_fringes(rows=True) without a row code (structured_light.reflection_filter "
                             "'auto' or 'global' in render mode builds one)")
        if self.fringe_mode == "quadrature":
            return self._render_quadrature(render_dir, seed, rows)
        n_fringe = len(self.periods) * self.steps
        names = self.layer_names if rows else self.layer_names[:n_fringe]
        what = f"{n_fringe} fringe layers ({len(self.periods)} periods x {self.steps} steps)"
        if rows:
            what += f" + {len(names) - n_fringe} row-code layers"
        return self._render_layers(names, render_dir, seed, ss, what, ambient=self.ambient)

    def _render_layers(self, names, render_dir, seed: int, ss: int, what: str, ambient: bool = False
                       ) -> tuple[np.ndarray, float]:
        """Layers `names` in one isolated Cycles call at `ss` x the camera grid, block-averaged to
        the camera resolution -> ((len(names), H, W) float32, wall seconds); with `ambient` the
        projector-off layer in the same call, into `ambient_image`."""
        from . import compat

        extra = [AMBIENT_LAYER] if ambient else []
        seconds = isolated_render(self.scene, self.renderer.tree, self.file_output, names + extra,
                                  render_dir, FRINGE_BASENAME, seed=seed, supersample=ss, filter_width=self.filter_width,
                                  what=what + (" + the projector-off layer" if ambient else ""),
                                  progress=self.renderer.progress)
        ch = compat.take_written_exr(render_dir, FRINGE_BASENAME, "fringe",
                                     expect=[f"{n}.V" for n in names + extra])
        if ambient:
            self.ambient_image = block_mean(ch.pop(f"{AMBIENT_LAYER}.V")[None].astype(np.float32), ss)[0]
        stack = np.stack([ch[f"{name}.V"] for name in names]).astype(np.float32)
        return block_mean(stack, ss), seconds

    def _render_quadrature(self, render_dir, seed: int, rows: bool) -> tuple[np.ndarray, float]:
        """Quadrature mode: each call of `quad_groups` (its row-code images only with `rows`), every
        phase step mixed from its white, cos and sin images (same seed: same paths) -> the render
        mode's stack layout (periods in config order, then the row code). Packed (`pack_channels`):
        three images per layer, taken back per point sample before the block mean
        (sl.unpack_basis: over one path the ratio to the white image is exact, whatever its colour)."""
        frames, seconds, i = {}, 0.0, 0
        for g, (per, rper, ss) in enumerate(self.quad_groups()):
            ambient = self.ambient and g == 0     # the first call is at `supersample`, the fringes' grid
            with_rows = rows and bool(rper)
            if self.pack_channels:       # the row code's layers come last: left out without `rows`
                layout = self._layout(per, rper)
                total, keep = len(layout), len(layout if with_rows else self._layout(per, ()))
            else:
                total, keep = sl.basis_size(len(per), rows=bool(rper)), sl.basis_size(len(per), rows=with_rows)
            names = self.layer_names[i:i + keep]
            i += total
            n_images = sl.basis_size(len(per), rows=with_rows)
            what = (f"{len(names)} quadrature layers ({n_images} images: white + cos, sin of {len(per)} periods"
                    + (" + the row code" if with_rows else "")
                    + (", three per layer in R, G, B)" if self.pack_channels else ")"))
            if self.pack_channels:
                stack, sec = self._render_packed(names, layout, render_dir, seed, ss, what, ambient)
            else:
                stack, sec = self._render_layers(names, render_dir, seed, ss, what, ambient)
            t0 = time.perf_counter()
            mixed = sl.frames_from_basis(stack, self.steps)
            seconds += sec + time.perf_counter() - t0
            keys = [("x", K) for K in per] + ([("y", K) for K in rper] if with_rows else [])
            frames.update({k: mixed[j * self.steps:(j + 1) * self.steps] for j, k in enumerate(keys)})
        order = [("x", K) for K in self.periods] + ([("y", K) for K in sl.scanner.ROW_PERIODS] if rows else [])
        return np.concatenate([frames[k] for k in order]), seconds

    def _render_packed(self, names, layout, render_dir, seed: int, ss: int, what: str, ambient: bool = False
                       ) -> tuple[np.ndarray, float]:
        """Packed quadrature layers `names` (white first) in one isolated Cycles call -> (the basis
        radiance (n, H, W) float32 at the camera resolution, grey as if each image were rendered
        alone: sl.unpack_basis per point sample, then the block mean; wall seconds); with `ambient`
        the projector-off layer (grey) in the same call, into `ambient_image`."""
        from . import compat

        extra = [AMBIENT_LAYER] if ambient else []
        seconds = isolated_render(self.scene, self.renderer.tree, self.file_output, names + extra,
                                  render_dir, FRINGE_BASENAME, seed=seed, supersample=ss, filter_width=self.filter_width,
                                  what=what + (" + the projector-off layer" if ambient else ""),
                                  progress=self.renderer.progress)
        t0 = time.perf_counter()
        grey_name = names[0] + GREY_SUFFIX
        expect = [f"{n}.{c}" for n in names for c in "RGB"] + [f"{grey_name}.V"] + [f"{n}.V" for n in extra]
        ch = compat.take_written_exr(render_dir, FRINGE_BASENAME, "fringe", expect=expect)
        if ambient:
            self.ambient_image = block_mean(ch.pop(f"{AMBIENT_LAYER}.V")[None].astype(np.float32), ss)[0]
        grey = ch.pop(f"{grey_name}.V")
        rgb = np.empty((len(names), 3) + grey.shape, np.float32)      # planar, as the EXR holds them
        for li, n in enumerate(names):
            for c, cn in enumerate("RGB"):
                rgb[li, c] = ch.pop(f"{n}.{cn}")
        basis = sl.unpack_basis(rgb, grey, layout)
        del rgb, ch
        return block_mean(basis, ss), seconds + time.perf_counter() - t0

    def process(self, rdir: Path, seed: int, T_world_cam) -> tuple[dict[str, Path], dict]:
        """Render the fringes, scan them, write the maps; returns ({kind: written file}, the render's
        structured_light record for scene.json)."""
        s = self.cfg.structured_light
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
            "periods": self.periods, "steps": self.steps, "unwrap": summary["unwrap"], "samples": int(s.samples),
            "fringe_mode": self.fringe_mode, "sensor": s.sensor, "exposure": summary["exposure"], "exposure_mode": summary["exposure_mode"],
            "hdr": summary["hdr"], "reflection_filter": summary["reflection_filter"], "glossy_fringes": ("offset" if self.flat is not None
                                                        else "sharp" if self.sharp_glossy else "blurred"),
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
        tree = self.renderer.tree
        if tree is not None:
            for n in [*self._rl_nodes, self.file_output]:
                if n is not None and tree.nodes.get(n.name) is not None:
                    tree.nodes.remove(n)
        self._rl_nodes, self.file_output = [], None
        if self.flat is not None:
            self.flat.teardown()
            self.flat = None
            return
        self.projector.teardown()
        self.layers, self.layer_names = [], []


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


def regularize_indirect(nt, gain, offset=0.5) -> None:
    """Make a projector light's node tree emit, for light on paths with a bounce (Light Path
    Diffuse Depth + g * Glossy Depth > 0.5; direct light has both 0, measured; g = 0 when the
    scene has shiny surfaces, `set_sharp_glossy`), the pattern blurred by INDIRECT_BLUR_PX:
    offset + gain * (pattern - offset), times the image's alpha (no light outside the projector
    image). Direct light, and with g = 0 mirror images, see the sharp pattern. `gain` and `offset`
    are numbers (a grey pattern) or one per colour channel (R, G, B: a packed quadrature layer,
    a different image in each channel, sl.pack_basis).

    Why: with a few paths per pixel the inter-reflected part of a fine fringe is Monte-Carlo noise
    (each path picks up the pattern at one random point of another surface), while physically a
    diffuse bounce averages the fine pattern over a footprint of many periods (the reason fine
    fringes resist inter-reflections). The blur is that average, done analytically
    (`indirect_gain`): with the default 32 px blur on a 912 px projector the 64-period fringe keeps
    ~0 of its modulation after a bounce (its light still adds to the offset, lowering the
    contrast), the 8-period 21%, the 1-period 98%, so the coarse patterns keep their real
    inter-reflection bias. A glossy bounce keeps the fine pattern: its lobe is narrow, and Monte
    Carlo over the lobe blurs it as much as the surface's roughness does."""
    tex = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeTexImage")
    em = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeEmission")
    N, L = nt.nodes, nt.links
    # per channel: vector maths on the colour (a grey pattern keeps the scalar nodes it always had,
    # so the render mode's lights are unchanged to the last bit)
    math = "ShaderNodeVectorMath" if np.ndim(gain) else "ShaderNodeMath"
    lp = N.new("ShaderNodeLightPath")
    bounces = N.new("ShaderNodeMath"); bounces.operation = "MULTIPLY_ADD"  # glossy * g + diffuse depth
    bounces.name = GLOSSY_NODE
    bounces.inputs[1].default_value = 1.0             # g = 1: glossy bounces blurred too (set_sharp_glossy)
    ind = N.new("ShaderNodeMath"); ind.operation = "GREATER_THAN"
    ind.inputs[1].default_value = 0.5                 # direct light: both depths 0 (measured)
    blur = N.new(math); blur.operation = "MULTIPLY_ADD"       # tex * gain + offset (1 - gain)
    blur.name = INDIRECT_NODE
    _set_gain(blur, gain, offset)
    clip = N.new(math); clip.operation = "MULTIPLY"           # x alpha: dark outside the image
    diff = N.new(math); diff.operation = "SUBTRACT"           # blurred - sharp
    out = N.new(math); out.operation = "MULTIPLY_ADD"         # ind * diff + sharp
    L.new(lp.outputs["Glossy Depth"], bounces.inputs[0])
    L.new(lp.outputs["Diffuse Depth"], bounces.inputs[2])
    L.new(bounces.outputs[0], ind.inputs[0])
    L.new(tex.outputs["Color"], blur.inputs[0])
    L.new(blur.outputs[0], clip.inputs[0])
    L.new(tex.outputs["Alpha"], clip.inputs[1])
    L.new(clip.outputs[0], diff.inputs[0])
    L.new(tex.outputs["Color"], diff.inputs[1])
    L.new(ind.outputs[0], out.inputs[0])
    L.new(diff.outputs[0], out.inputs[1])
    L.new(tex.outputs["Color"], out.inputs[2])
    L.new(out.outputs[0], em.inputs["Color"])


def _set_gain(node, gain, offset=0.5) -> None:
    if np.ndim(gain):
        g, o = np.asarray(gain, float), np.broadcast_to(np.asarray(offset, float), (3,))
        node.inputs[1].default_value = tuple(g)
        node.inputs[2].default_value = tuple(o * (1.0 - g))
        return
    node.inputs[1].default_value = float(gain)
    node.inputs[2].default_value = float(offset * (1.0 - gain))


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
