"""The path-traced fringe strategies' shared Blender side (`PatternLights`: one projector light and
view layer per projector image, the fringe call's File Output node, the bounce blur of
`regularize_indirect`) and `RenderFringes`, `structured_light.fringe_mode` "render": every pattern
path-traced in its own layer, the reference. Quadrature mode builds on the same lights
(core/fringe_quadrature.py); fast mode renders one flat-lit layer instead (core/fringe_fast.py).
Why the fringes are rendered this way (point samples, one seed, the bounce blur, sharp glossy
bounces): core/structured_light.py's module doc.
"""
from __future__ import annotations

import numpy as np

from .fringe_call import block_mean, indirect_gain, isolated_render, link_ambient_layer
from .projector import AMBIENT_LAYER, LIGHTS_COLLECTION, Projector

FRINGE_BASENAME = "_sl_fringes"  # the fringe call's multilayer EXR in the render folder (deleted)
OUTPUT_NODE = "datapipe_sl_file_output"
INDIRECT_NODE = "datapipe_sl_indirect_blur"
GLOSSY_NODE = "datapipe_sl_glossy_switch"
GREY_SUFFIX = "_grey"            # a packed white layer's grey value, written beside its R, G, B


class PatternLights:
    """A path-traced fringe strategy: the projector images of `patterns()` as pattern lights (their
    bounced light blurred, `light_gains()`), one view layer each, written by one File Output node.
    `cam` is the StructuredLightCamera that holds it: its config, scene, camera, renderer, plan,
    scanner and render settings (supersample, filter_width, layer_samples, indirect_blur_px)."""

    packed = False                  # three images per layer, one per colour channel (quadrature)

    def __init__(self, cam):
        self.cam = cam
        self.projector = None
        self.layers: list = []
        self.layer_names: list[str] = []      # the fringe layers, then the row code's (when the plan has one)
        self.file_output = None
        self._rl_nodes: list = []

    def patterns(self) -> np.ndarray:
        raise NotImplementedError

    def light_gains(self) -> list:
        raise NotImplementedError

    def white_layers(self) -> list[int]:
        """Indices of the packed white layers, also written as grey (none unless packed)."""
        return []

    def setup(self) -> None:
        import bpy
        from . import compat

        cam = self.cam
        patterns = self.patterns()
        self.projector = Projector(cam.cfg, cam.scene, cam.camera.obj)
        self.projector.build(patterns)
        for ob, (gain, offset) in zip(self.projector.lights, self.light_gains()):
            regularize_indirect(ob.data.node_tree, gain, offset)
        self.layers = self.projector.make_view_layers(exclude=[LIGHTS_COLLECTION], samples=cam.layer_samples)
        self.layer_names = [vl.name for vl in self.layers]
        tree = cam.renderer.tree
        self.file_output = compat.new_file_output(tree, bpy.app.tempdir or "/tmp", FRINGE_BASENAME,
                                                  name=OUTPUT_NODE)
        if cam.plan.ambient:
            self._rl_nodes.append(link_ambient_layer(self.projector, tree, cam.scene, self.file_output,
                                                     f"{OUTPUT_NODE}_rl_ambient", cam.layer_samples))
        whites = set(self.white_layers())
        for i, vl in enumerate(self.layers):
            vl.use = False                   # rendered only by render(), not by the native call
            rl = compat.render_layers_node(tree, cam.scene, vl.name, name=f"{OUTPUT_NODE}_rl_{i:02d}")
            rl.location = (-700, -300 * i)
            image = compat.rl_socket(rl, "image")
            # a grey layer is written as the compositor's grey value (its luminance), the frame a
            # monochrome camera takes; a packed one as R, G, B, and its white layer also as grey
            tree.links.new(image, compat.file_output_add_input(self.file_output, vl.name,
                                                               "RGBA" if self.packed else "FLOAT"))
            if i in whites:
                tree.links.new(image, compat.file_output_add_input(self.file_output, vl.name + GREY_SUFFIX, "FLOAT"))
            self._rl_nodes.append(rl)
        self.file_output.format.exr_codec = "NONE"     # a scratch file: no time spent compressing
        self.file_output.mute = True

    def set_samples(self, layer_samples: int) -> None:
        for vl in self.layers:
            vl.samples = layer_samples
        if self.cam.plan.ambient:
            self.cam.scene.view_layers[AMBIENT_LAYER].samples = layer_samples

    def set_indirect_blur(self, blur_px: float) -> None:
        """Set every light's bounce blur to `blur_px` (the camera's indirect_blur_px, `gain`)."""
        for ob, (gain, offset) in zip(self.projector.lights, self.light_gains()):
            _set_gain(ob.data.node_tree.nodes[INDIRECT_NODE], gain, offset)

    def set_sharp_glossy(self, sharp: bool) -> None:
        for ob in self.projector.lights:
            ob.data.node_tree.nodes[GLOSSY_NODE].inputs[1].default_value = 0.0 if sharp else 1.0

    def glossy_fringes(self, sharp: bool) -> str:
        """The scene.json record of what glossy bounces see."""
        return "sharp" if sharp else "blurred"

    def check_rows(self, rows: bool) -> None:
        if rows and not self.cam.plan.row_code:
            raise ValueError("render_fringes(rows=True) without a row code (structured_light.reflection_filter "
                             "'auto' or 'global' in render mode builds one)")

    def gain(self, K, length: int) -> float:
        """The modulation a K-period fringe over `length` projector pixels keeps after a bounce."""
        return indirect_gain(K, length, self.cam.indirect_blur_px)

    def render_layers(self, names, render_dir, seed: int, ss: int, what: str, ambient: bool = False):
        """Layers `names` in one isolated Cycles call at `ss` x the camera grid, block-averaged to
        the camera resolution -> ((len(names), H, W) float32, wall seconds, the projector-off
        layer's (H, W) float32 image from the same call with `ambient`, else None)."""
        from . import compat

        extra = [AMBIENT_LAYER] if ambient else []
        seconds = self.isolated_call(names + extra, render_dir, seed, ss, what, ambient)
        ch = compat.take_written_exr(render_dir, FRINGE_BASENAME, "fringe",
                                     expect=[f"{n}.V" for n in names + extra])
        amb = block_mean(ch.pop(f"{AMBIENT_LAYER}.V")[None].astype(np.float32), ss)[0] if ambient else None
        stack = np.stack([ch[f"{name}.V"] for name in names]).astype(np.float32)
        return block_mean(stack, ss), seconds, amb

    def isolated_call(self, names, render_dir, seed: int, ss: int, what: str, ambient: bool) -> float:
        cam = self.cam
        return isolated_render(cam.scene, cam.renderer.tree, self.file_output, names, render_dir, FRINGE_BASENAME,
                               seed=seed, supersample=ss, filter_width=cam.filter_width,
                               what=what + (" + the projector-off layer" if ambient else ""),
                               progress=cam.renderer.progress)

    def teardown(self) -> None:
        tree = self.cam.renderer.tree
        if tree is not None:
            for n in [*self._rl_nodes, self.file_output]:
                if n is not None and tree.nodes.get(n.name) is not None:
                    tree.nodes.remove(n)
        self._rl_nodes, self.file_output = [], None
        if self.projector is not None:
            self.projector.teardown()
        self.layers, self.layer_names = [], []


class RenderFringes(PatternLights):
    """fringe_mode "render": every pattern (F x N, then the row code's N when the plan has one)
    path-traced in a layer of its own, all in one Cycles call."""

    def patterns(self) -> np.ndarray:
        from .. import sl

        cam = self.cam
        Wp, Hp = cam.proj_size
        gamma = cam.cfg.structured_light.projector_gamma
        patterns = sl.fringe_patterns(Wp, Hp, cam.plan.periods, cam.plan.steps, gamma=gamma)
        if cam.plan.row_code:              # the global reflection filter's row code (sl.Scanner.scan)
            patterns = np.concatenate([patterns, cam.scanner.row_patterns(gamma)])
        return patterns

    def light_gains(self) -> list[tuple[float, float]]:
        """(modulation a bounce keeps, the image's mean) of each pattern light: the fringes across
        the width, then the row code's over the height."""
        Wp, Hp = self.cam.proj_size
        plan = self.cam.plan
        out = [(self.gain(K, Wp), 0.5) for K in plan.periods for _ in range(plan.steps)]
        return out + [(self.gain(K, Hp), 0.5) for K in plan.row_periods for _ in range(plan.steps)]

    def render(self, render_dir, seed: int, T_world_cam, rows: bool):
        self.check_rows(rows)
        plan = self.cam.plan
        n_fringe = plan.n_fringe
        names = self.layer_names if rows else self.layer_names[:n_fringe]
        what = f"{n_fringe} fringe layers ({len(plan.periods)} periods x {plan.steps} steps)"
        if rows:
            what += f" + {len(names) - n_fringe} row-code layers"
        return self.render_layers(names, render_dir, seed, int(self.cam.supersample), what, ambient=plan.ambient)


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
