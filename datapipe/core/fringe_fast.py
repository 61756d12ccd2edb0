"""The fast fringe render (`structured_light.fringe_mode = "fast"`): ONE Cycles call with the
projector showing a white image, from which `sl.fringe_synth` makes every fringe image.

Why it is exact for direct light: the projector is a point light, so the light that reaches a
surface point straight from it is the white-image radiance times the pattern value at that point's
projector coordinate (the light's emission is the pattern, the geometry, shadow and BRDF are the
same in every frame). With point samples (FRINGE_FILTER_WIDTH, as in the render mode) every
sub-pixel sample sees one surface point, whose world position the Position pass gives; the same
`P_proj` the decoder triangulates with turns it into the projector column. A point light's direct
light has no Monte-Carlo noise (one shadow ray, no choice), so the synthesised direct terms equal
the render mode's pattern by pattern (tests/blender/test_fringe_fast.py).

Light passes (Cycles, verified in bpy 5.0.1): the Diffuse/Glossy/Transmission *Direct* passes hold
the light without the surface colour, the *Color* passes the colour, so

    direct   = DiffDir * DiffCol + GlossDir * GlossCol + TransDir * TransCol
    indirect = Combined - direct

Each is written as one float channel (the compositor's colour -> float conversion is linear, and
the direct passes of a white light are grey, so converting the product or the factors agrees).

Bounced light (the `indirect` term) reaches a point after a bounce somewhere else, where the
pattern is unknown here. Every frame gets the indirect light of the white image times the
pattern's mean (0.5): offset only, no modulation. That is what the render mode's
`regularize_indirect` makes of the finest fringe (its bounce modulation is blurred to ~0). The
coarse fringes keep much of their modulation after a bounce (1 period 98%, 8 periods 21%) and its
inter-reflection bias decides fringe orders next to walls, so for every period whose gain is at
least BOUNCE_MIN_GAIN a second Cycles call renders, at the camera resolution with BOUNCE_SAMPLES
paths per pixel, the bounce light only (the light's emission is zero for camera-visible direct
light) of a white image and of two quadrature fringes (cos, sin); `sl.bounce_modulation` turns
them into every step's bounce fringe (linearity). One path per pixel is mostly noise, and so are
4 (the render mode's coarse fringes: two Cycles seeds share only 15% of their wrong-order pixels,
benchmarks/results/sl_fringe_modes.md); what varies slowly is the bounce fringe's ratio to the
bounce light of the same paths, so that ratio is taken of maps smoothed by BOUNCE_SMOOTH_PX and
multiplied by the flat render's bounce light: the expected bounce fringe, at 5 layers of 1/4 of
the flat render's paths each.

Glossy bounces: the fine fringe's bounce light is offset only here, also where a shiny part
mirrors it sharply (the render mode with sharp glossy bounces shows those reflections as a biased
phase; the fast mode only as lower contrast): the fast mode is optimistic on shiny parts, which
`fringe_mode` "auto" therefore renders in quadrature mode (sl/fringe_basis.py: every light path,
white + cos + sin per period).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import sl
from ..geometry import projector_matrix, projector_resolution
from .projector import AMBIENT_LAYER, LIGHTS_COLLECTION, Projector
from .fringe_call import INDIRECT_BLUR_PX, block_mean, indirect_gain, isolated_render, link_ambient_layer

BOUNCE_MIN_GAIN = 0.05     # periods whose bounce keeps at least this modulation get bounce layers
BOUNCE_SAMPLES = 1         # paths per camera pixel of the bounce layers (camera resolution)
BOUNCE_SMOOTH_PX = 2.0     # camera px: Gaussian smoothing of the bounce fringe's ratio to the bounce light
BOUNCE_BASENAME = "_sl_bounce"

FLAT_BASENAME = "_sl_flat"               # the flat-lit call's multilayer EXR in the render folder (deleted)
FLAT_NODE = "datapipe_sl_file_output_flat"    # starts with fringe_render.OUTPUT_NODE: removed as a leftover
BOUNCE_NODE = "datapipe_sl_file_output_bounce"
# EXR item -> (Render Layers socket, view-layer pass flag, socket type)
PASSES = {
    "combined": ("Image", None, "FLOAT"),
    "diff_dir": ("Diffuse Direct", "use_pass_diffuse_direct", "FLOAT"),
    "diff_col": ("Diffuse Color", "use_pass_diffuse_color", "FLOAT"),
    "gloss_dir": ("Glossy Direct", "use_pass_glossy_direct", "FLOAT"),
    "gloss_col": ("Glossy Color", "use_pass_glossy_color", "FLOAT"),
    "trans_dir": ("Transmission Direct", "use_pass_transmission_direct", "FLOAT"),
    "trans_col": ("Transmission Color", "use_pass_transmission_color", "FLOAT"),
    "position": ("Position", "use_pass_position", "VECTOR"),
}


class FastFringes:
    """The fringe strategy of fringe_mode "fast" (the StructuredLightCamera `cam` holds it): the
    flat-lit call (`FlatLitRender`) and every pattern synthesised from it on the same point grid.
    `bounce_min_gain`: periods whose bounce keeps this modulation get bounce layers (None:
    BOUNCE_MIN_GAIN; the run's FringePlan carries it, benchmarks vary it)."""

    def __init__(self, cam, *, bounce_min_gain: float | None = None):
        self.cam = cam
        self.bounce_min_gain = BOUNCE_MIN_GAIN if bounce_min_gain is None else float(bounce_min_gain)
        self.flat = None
        self._profiles = sl.pattern_profiles(cam.proj_size[0], cam.plan.periods, cam.plan.steps)

    @property
    def file_output(self):
        """The File Output node the flat-lit call writes through."""
        return None if self.flat is None else self.flat.file_output

    @property
    def layer_names(self) -> list[str]:
        return [] if self.flat is None else self.flat.layer_names

    def setup(self) -> None:
        c = self.cam
        self.flat = FlatLitRender(c.cfg, c.scene, c.camera, c.renderer, min_gain=self.bounce_min_gain)
        self.flat.setup()

    # the flat-lit call gets its samples per render; bounced light is offset only for the fine
    # fringe (and, sharp or not, for glossy bounces): nothing to set on the lights
    def set_samples(self, layer_samples: int) -> None:
        pass

    def set_indirect_blur(self, blur_px: float) -> None:
        pass

    def set_sharp_glossy(self, sharp: bool) -> None:
        pass

    def glossy_fringes(self, sharp: bool) -> str:
        return "offset"

    def render(self, render_dir, seed: int, T_world_cam, rows: bool):
        """The flat-lit call -> ((F*N, H, W) float32 synthesised fringes, wall seconds of the call and
        the synthesis, the projector-off image or None). No row code in fast mode: `rows` is unused.
        `T_world_cam` (the pose P_proj is made from) defaults to the camera's current pose."""
        c = self.cam
        ss = int(c.supersample)
        if T_world_cam is None:
            T_world_cam = c.camera.T_world_cam()
        lit, seconds = self.flat.render(render_dir, seed, supersample=ss, filter_width=c.filter_width,
                                        samples=c.layer_samples)
        t0 = time.perf_counter()
        ambient = block_mean(lit.ambient[None], ss)[0] if lit.ambient is not None else None
        stack = sl.synthesize_fringes(lit.direct, lit.indirect, lit.points, projector_matrix(c.cfg, T_world_cam),
                                      self._profiles, block=ss)
        bounce = lit.bounce(c.plan.periods, c.plan.steps, ss)
        if bounce is not None:
            stack += bounce
        return stack, seconds + time.perf_counter() - t0, ambient

    def teardown(self) -> None:
        if self.flat is not None:
            self.flat.teardown()
            self.flat = None


class FlatLitRender:
    """The projector with a white image in one view layer (+ the bounce layers of the coarse
    periods); `render()` -> direct, indirect and world position of every point sample of the
    supersampled grid, and {K: (C_K, S_K)} bounce maps at the camera resolution.

    >>> flat = FlatLitRender(cfg, bpy_scene, camera, renderer); flat.setup()
    >>> lit, seconds = flat.render(render_dir, seed, supersample=2, filter_width=0.01, samples=1)
    """

    def __init__(self, cfg, bpy_scene, camera, renderer, *, min_gain: float = BOUNCE_MIN_GAIN,
                 blur_px: float = INDIRECT_BLUR_PX):
        self.cfg, self.scene, self.camera, self.renderer = cfg, bpy_scene, camera, renderer
        Wp = projector_resolution(cfg)[0]
        gains = {K: indirect_gain(K, Wp, blur_px) for K in cfg.structured_light.periods}
        self.gains = {K: g for K, g in gains.items() if g >= min_gain}   # periods with bounce layers
        self.bounce_samples = BOUNCE_SAMPLES
        self.ambient = cfg.structured_light.ambient == "scene"   # the projector-off layer in the flat call
        self.projector = None
        self.layer_names: list[str] = []      # [flat, bounce white, (cos, sin) per period in gains]
        self._nodes: list = []
        self.file_output = self.bounce_output = None

    def setup(self) -> None:
        import bpy
        from . import compat

        Wp, Hp = projector_resolution(self.cfg)
        images = [np.ones(Wp, np.float32)]
        if self.gains:
            images.append(np.ones(Wp, np.float32))
            for K in self.gains:
                images += list(sl.quadrature_profiles(Wp, K))
        self.projector = Projector(self.cfg, self.scene, self.camera.obj)
        self.projector.build(np.stack([np.broadcast_to(im, (Hp, Wp)) for im in images]))
        layers = self.projector.make_view_layers(exclude=[LIGHTS_COLLECTION])
        self.layer_names = [vl.name for vl in layers]
        for ob in self.projector.lights[1:]:
            bounce_only(ob.data.node_tree)
        for _, flag, _ in PASSES.values():
            if flag:
                setattr(layers[0], flag, True)
        for vl in layers:
            vl.use = False                      # rendered only by render(), not by the native call
        tree = self.renderer.tree
        tmp = bpy.app.tempdir or "/tmp"
        self.file_output = compat.new_file_output(tree, tmp, FLAT_BASENAME, name=FLAT_NODE)
        rl = compat.render_layers_node(tree, self.scene, layers[0].name, name=f"{FLAT_NODE}_rl")
        self._nodes = [rl]
        for item, (socket, _, stype) in PASSES.items():
            tree.links.new(rl.outputs[socket], compat.file_output_add_input(self.file_output, item, stype))
        if self.ambient:
            self._nodes.append(link_ambient_layer(self.projector, tree, self.scene, self.file_output,
                                                  f"{FLAT_NODE}_ambient", 1))
        outputs = [self.file_output]
        if len(layers) > 1:
            self.bounce_output = compat.new_file_output(tree, tmp, BOUNCE_BASENAME, name=BOUNCE_NODE)
            outputs.append(self.bounce_output)
            for vl in layers[1:]:
                rl = compat.render_layers_node(tree, self.scene, vl.name, name=f"{BOUNCE_NODE}_{vl.name}")
                self._nodes.append(rl)
                tree.links.new(compat.rl_socket(rl, "image"),
                               compat.file_output_add_input(self.bounce_output, vl.name, "FLOAT"))
        for fo in outputs:
            fo.format.exr_codec = "NONE"        # scratch files: no time spent compressing
            fo.mute = True

    def render(self, render_dir, seed: int, *, supersample: int, filter_width: float, samples: int):
        """The flat-lit call at `supersample` x the camera resolution (`samples` paths per point
        sample) and, with bounce layers, the bounce call at the camera resolution -> (FlatLit,
        wall seconds of both)."""
        from . import compat

        render_dir = Path(render_dir)
        vls = [self.scene.view_layers[n] for n in self.layer_names]
        vls[0].samples = int(samples)
        for vl in vls[1:]:
            vl.samples = int(self.bounce_samples)
        extra = [AMBIENT_LAYER] if self.ambient else []
        if extra:
            self.scene.view_layers[AMBIENT_LAYER].samples = int(samples)
        seconds = isolated_render(self.scene, self.renderer.tree, self.file_output, self.layer_names[:1] + extra,
                                  render_dir, FLAT_BASENAME, seed=seed, supersample=supersample,
                                  filter_width=filter_width, what="fast mode: flat-lit layer"
                                  + (" + the projector-off layer" if extra else ""), progress=self.renderer.progress)
        ch = compat.take_written_exr(render_dir, FLAT_BASENAME, "flat-lit fringe", expect=[
            f"{k}.V" for k, (_, _, t) in PASSES.items() if t == "FLOAT"] + [f"position.{c}" for c in "XYZ"]
            + [f"{n}.V" for n in extra])
        ambient = ch.pop(f"{AMBIENT_LAYER}.V").astype(np.float32) if extra else None
        g = {k: ch[f"{k}.V"].astype(np.float32) for k, (_, _, t) in PASSES.items() if t == "FLOAT"}
        direct = g["diff_dir"] * g["diff_col"] + g["gloss_dir"] * g["gloss_col"] + g["trans_dir"] * g["trans_col"]
        indirect = np.maximum(g["combined"] - direct, 0.0)
        pos = np.stack([ch[f"position.{c}"] for c in "XYZ"], -1).astype(np.float64)
        quadrature, white = {}, None
        if self.bounce_output is not None:
            seconds += isolated_render(self.scene, self.renderer.tree, self.bounce_output, self.layer_names[1:],
                                       render_dir, BOUNCE_BASENAME, seed=seed, supersample=1,
                                       filter_width=filter_width,
                                       what=f"fast mode: {len(self.layer_names) - 1} bounce layers",
                                       progress=self.renderer.progress)
            ch = compat.take_written_exr(render_dir, BOUNCE_BASENAME, "bounce fringe",
                                         expect=[f"{n}.V" for n in self.layer_names[1:]])
            b = [ch[f"{n}.V"].astype(np.float32) for n in self.layer_names[1:]]
            white = b[0]
            for i, K in enumerate(self.gains):          # signed fringes: 2 x (0.5 + 0.5 cos) - 1
                quadrature[K] = (2 * b[1 + 2 * i] - b[0], 2 * b[2 + 2 * i] - b[0])
        return FlatLit(direct, indirect, pos, quadrature, dict(self.gains), white, ambient), seconds

    def teardown(self) -> None:
        tree = self.renderer.tree
        if tree is not None:
            for n in [*self._nodes, self.file_output, self.bounce_output]:
                if n is not None and tree.nodes.get(n.name) is not None:
                    tree.nodes.remove(n)
        self._nodes, self.file_output, self.bounce_output = [], None, None
        if self.projector is not None:
            self.projector.teardown()
            self.projector = None


@dataclass
class FlatLit:
    """One flat-lit render: (h, w) float32 `direct` and `indirect` radiance of the white image on
    the point-sample grid, (h, w, 3) world `points` (meaningless where nothing was hit, where both
    light terms are 0), and the bounce maps {K: (C_K, S_K)} (H, W) at the camera resolution with
    their `gains` and the bounce light of the white image from the same paths (`white`); with
    structured_light.ambient "scene" the projector-off layer's radiance on the point-sample grid
    (`ambient`)."""
    direct: np.ndarray
    indirect: np.ndarray
    points: np.ndarray
    quadrature: dict
    gains: dict
    white: np.ndarray | None = None
    ambient: np.ndarray | None = None

    def bounce(self, periods, steps: int, block: int, smooth_px: float = BOUNCE_SMOOTH_PX):
        """(F*N, H, W) bounce fringes of the patterns (sl.bounce_modulation), None without bounce layers."""
        if not self.quadrature:
            return None
        h, w = self.indirect.shape
        ind = self.indirect.reshape(h // block, block, w // block, block).mean(axis=(1, 3))
        return sl.bounce_modulation(self.quadrature, periods, steps, self.gains, white=self.white,
                                    indirect=ind, smooth_px=smooth_px)


def bounce_only(nt) -> None:
    """Make a projector light emit for bounced light only (Light Path Ray Depth > 1; in a light
    shader direct light has depth 1): its image times 0 or 1 before the Emission colour."""
    tex = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeTexImage")
    em = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeEmission")
    lp = nt.nodes.new("ShaderNodeLightPath")
    ind = nt.nodes.new("ShaderNodeMath"); ind.operation = "GREATER_THAN"
    ind.inputs[1].default_value = 1.5
    mul = nt.nodes.new("ShaderNodeMath"); mul.operation = "MULTIPLY"
    nt.links.new(lp.outputs["Ray Depth"], ind.inputs[0])
    nt.links.new(tex.outputs["Color"], mul.inputs[0])
    nt.links.new(ind.outputs[0], mul.inputs[1])
    nt.links.new(mul.outputs[0], em.inputs["Color"])
