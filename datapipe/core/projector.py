"""The fringe projector: one Cycles spot light per pattern, parented to the camera.

The pure math (no bpy) lives in datapipe.geometry: `projector_intrinsics`,
`projector_pose_blender`, `T_cam_proj`, `projector_matrix`, `texture_mapping`, `spot_size`,
`pattern_pixels`, `check_patterns`. Here: the Blender side (`Projector`, `make_fringe_view_layers`,
`fringe_layer_leaks`); the frames and the node-tree mapping are derived below.

Frames
------
The light is parented to the camera object with the pose `cfg.projector.location/rotation` given in
the camera object's local (Blender) axes. Like a Blender camera, the spot light looks down its local
-Z with +Y up. The *OpenCV projector frame* is the light's frame turned 180 degrees about X
(x right, y down, z forward), exactly as for the camera, so

    T_cam_proj = B @ T_blcam_bllight @ B          (B = geometry.BLENDER_TO_OPENCV)
    P_proj     = K_p @ inv(T_world_cam @ T_cam_proj)[:3]

with `K_p = intrinsics_from_sensor(focal, sensor_width, W, H)` (pixel centres at integers,
cx = W/2 - 0.5, cy = H/2 - 0.5). Projector column x / row y (OpenCV, rows down) is what P_proj
returns; pattern array element `[y, x]` is what that point receives.

Node tree (per light)
---------------------
    TexCoord.Normal -> (N.x/N.z, N.y/N.z, 0) -> Mapping(scale, location) -> Image(CLIP) -> Emission

In a light shader Cycles' TexCoord "Normal" is the direction between the light and the shaded
point, in the light's object space (verified: with a rotated camera and a rotated, offset
projector the decoded columns match P_proj to 0.001 px, tests/blender/test_projector.py). Whatever its sign, the ratios are u = d.x/d.z, v = d.y/d.z
for d = the point in light coordinates (d.z < 0 in front of the light). In the OpenCV projector
frame (x, y, z) = (d.x, -d.y, -d.z), so the normalised image coordinates are
xn = x/z = -u and yn = y/z = v, and the pixel is x = fx*xn + cx, y = fy*yn + cy.

Blender image texture coordinates (s, t) span [0, 1] over the image's outer pixel edges, texel i's
centre at (i + 0.5)/W, and t = 0 at the bottom row of the stored image. The pattern is stored
flipped (numpy row 0 = top of the projected image = Blender's last row), so

    s = (x + 0.5)/W     = -fx/W * u + (cx + 0.5)/W
    t = 1 - (y + 0.5)/H = -fy/H * v + 1 - (cy + 0.5)/H

Mapping (type POINT: out = location + scale * in) therefore gets
scale = (-fx/W, -fy/H, 1), location = ((cx + 0.5)/W, 1 - (cy + 0.5)/H, 0); for an unshifted
projector fx/W = focal_mm/sensor_width_mm (sensor fit horizontal), fy = fx, location = (0.5, 0.5).
The two negative scales are the "180 degrees about z" of the original DataPipe.

Interpolation: 'Linear' (default) samples texel i exactly at its centre, s = (i + 0.5)/W, and
interpolates linearly in between, so the continuous pattern is the piecewise-linear interpolant of
I(x) through the integer columns: its phase at any continuous x is I's phase at x (no half-pixel
shift), and sinusoidal fringes stay sinusoidal to within the interpolation error. 'Closest' returns
texel floor(s*W), i.e. texel i covers x in [i - 0.5, i + 0.5) around its centre: also the right
mapping (a pixelated DMD), but a camera pixel smaller than a projector pixel then sees a staircase
(decoded x quantised to whole projector pixels). Extension 'CLIP' returns 0 outside the image, so
the image (not the spot cone, which is made a little wider) is the aperture; with 'Linear' the outer
half texel fades to zero.

Radiometry: a spot light is a point source with radiant intensity energy/(4*pi) W/sr times the
node tree's emission (pattern value * cfg.projector.power). The irradiance on a surface therefore
falls off with 1/d^2 and cos(incidence); because the image is spread over the tangent plane
(TexCoord.Normal / z), a fronto-parallel plane receives an extra cos^3(off-axis angle) towards the
image corners (a real projector with equal flux per pixel would not). Both are physical-looking,
smooth, and cancel in phase-shift decoding (only the modulation B changes).
"""
from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from ..errors import DataPipeError
from ..geometry import (check_patterns, pattern_pixels, projector_cfg, projector_intrinsics, projector_matrix,
                        projector_pose_blender, projector_resolution, spot_size, texture_mapping, T_cam_proj)

LIGHTS_COLLECTION = "datapipe_lights"       # the scene's own lights (BlendScene); excluded from fringe layers
COLLECTION_PREFIX = "datapipe_sl_"          # one collection per projector light: datapipe_sl_00, ...
LAYER_PREFIX = "sl_"                        # one view layer per pattern: sl_00, ...
AMBIENT_LAYER = "sl_ambient"                # the projector-off view layer (structured_light.ambient "scene")
IMAGE_PREFIX = "datapipe_sl_pattern_"
LIGHT_PREFIX = "datapipe_projector_"
PROJECTOR_ENERGY_W = 10.0                   # light power (W); the pattern value * power scales it
INTERPOLATIONS = ("Linear", "Closest")


def collection_name(i: int) -> str:
    return f"{COLLECTION_PREFIX}{i:02d}"


def layer_name(i: int) -> str:
    return f"{LAYER_PREFIX}{i:02d}"


# ------------------------------------------------------------------------------------------------
# Blender side

SPOT_BLEND = 1e-4     # the spot cone's soft edge, outside the image (see build())


class Projector:
    """Spot-light projector(s) parented to `camera_obj`; one light + collection per pattern.

    >>> proj = Projector(cfg, scene, camera.obj)
    >>> proj.build(patterns)                      # (P, H, W), row 0 = top, pattern formula of docs/CONVENTIONS.md
    >>> proj.make_view_layers()                   # sl_00 .. sl_{P-1}; other layers exclude the projectors
    >>> P = proj.P_proj(T_world_cam)              # == projector_matrix(cfg, T_world_cam)
    >>> proj.teardown()                           # removes lights, images, collections, view layers

    `cfg` is the full Config (projector + structured_light sections are read).
    """

    def __init__(self, cfg, bpy_scene, camera_obj, *, interpolation: str = "Linear",
                 energy: float = PROJECTOR_ENERGY_W):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
        self.cfg = cfg
        self.scene = bpy_scene
        self.camera_obj = camera_obj
        self.interpolation = interpolation
        self.energy = float(energy)
        self.K = projector_intrinsics(cfg)
        self.resolution = projector_resolution(cfg)
        self.T_cam_proj = T_cam_proj(cfg)
        self.lights: list = []             # light objects, one per pattern
        self.collections: list = []        # their collections datapipe_sl_NN
        self.images: list = []             # their pattern images
        self.layer_names: list[str] = []   # fringe view layers made by make_view_layers
        self.ambient_layer_name: str | None = None   # the projector-off layer (make_ambient_layer)

    @property
    def view_layers(self) -> list:
        """The fringe view layers (looked up by name: a removed layer is never touched)."""
        return [self.scene.view_layers[n] for n in self.layer_names if n in self.scene.view_layers]

    # -- math on the live camera ------------------------------------------------------------------
    def P_proj(self, T_world_cam=None) -> np.ndarray:
        """P_proj for `T_world_cam` (OpenCV), default the camera object's current pose."""
        if T_world_cam is None:
            from ..geometry import blender_camera_to_opencv
            T_world_cam = blender_camera_to_opencv(_normalized(self.camera_obj.matrix_world))
        return projector_matrix(self.cfg, T_world_cam)

    # -- build ------------------------------------------------------------------------------------
    def build(self, patterns) -> list:
        """One spot light per pattern, each alone in its collection `datapipe_sl_NN` (linked to the
        scene's master collection), excluded from every existing view layer. Returns the
        collections. Building again first tears the previous build down (view layers included)."""
        import bpy
        from mathutils import Matrix

        arr = check_patterns(self.cfg, patterns)
        if self.lights or self.layer_names:
            self.teardown()
        w, h = self.resolution
        size = spot_size(self.cfg)
        scale, location = texture_mapping(self.cfg)
        T_local = _to_matrix(projector_pose_blender(self.cfg))
        # cancel a scaled camera object so the light's world matrix stays rigid
        sx, sy, sz = self.camera_obj.matrix_world.to_scale()
        parent_inv = Matrix.Diagonal((1.0 / sx, 1.0 / sy, 1.0 / sz, 1.0))
        power = projector_cfg(self.cfg).power
        for i, pat in enumerate(arr):
            img = bpy.data.images.new(f"{IMAGE_PREFIX}{i:02d}", w, h, alpha=True, float_buffer=True)
            img.colorspace_settings.name = "Non-Color"     # before the pixels: values arrive unchanged
            img.pixels.foreach_set(pattern_pixels(pat))
            img.update()
            self.images.append(img)

            ld = bpy.data.lights.new(f"{LIGHT_PREFIX}{i:02d}", "SPOT")
            ld.energy = self.energy
            ld.color = (1.0, 1.0, 1.0)
            ld.spot_size = size
            # not 0: with a zero blend Cycles' cone smoothstep divides 0 by 0 for a sample exactly on
            # the cone's edge and returns NaN there (measured: one NaN pixel in every fringe layer of a
            # 370 x 277 camera whose point samples hit the edge; the scanner refuses NaN). The blend
            # band is SPOT_BLEND x (1 - cos(half cone)) in cos, 1e-5 here, while the image ends
            # ~7e-3 inside the cone (SPOT_MARGIN): every image ray keeps attenuation 1, byte for byte.
            ld.spot_blend = SPOT_BLEND
            ld.shadow_soft_size = 0.0          # point source: sharp shadows
            ld.use_soft_falloff = False
            ld.use_shadow = True
            ld.use_nodes = True
            _build_node_tree(ld.node_tree, img, scale, location, self.interpolation, power)

            ob = bpy.data.objects.new(ld.name, ld)
            coll = bpy.data.collections.new(collection_name(i))
            self.scene.collection.children.link(coll)
            coll.objects.link(ob)
            ob.parent = self.camera_obj
            ob.matrix_parent_inverse = parent_inv
            ob.matrix_basis = T_local
            self.lights.append(ob)
            self.collections.append(coll)
        # a collection linked to the scene appears in every existing view layer: keep the
        # projectors out of all of them (native RGB must not see fringes)
        for vl in self.scene.view_layers:
            self.exclude_from(vl)
        return self.collections

    def exclude_from(self, view_layer) -> None:
        """Exclude every projector collection from `view_layer` (for layers made after build())."""
        for coll in self.collections:
            _set_exclude(view_layer, coll.name, True)

    def make_view_layers(self, exclude: Iterable = (LIGHTS_COLLECTION,), *, samples: int | None = None,
                         strict: bool = True) -> list:
        """One view layer per pattern (see `make_fringe_view_layers`) with `samples` Cycles paths per
        pixel (default structured_light.samples); remembered for teardown.

        Call it after every other view layer exists (it excludes the projectors from those)."""
        if not self.collections:
            raise DataPipeError("Projector.make_view_layers() before build() (fix: build the patterns first)")
        layers = make_fringe_view_layers(self.scene, self.collections, exclude=exclude, strict=False,
                                         samples=self.cfg.structured_light.samples if samples is None else samples)
        self.layer_names = [vl.name for vl in layers]
        if strict:
            _raise_on_leaks(self.scene, layers, self.collections)
        return layers

    def make_ambient_layer(self, samples: int):
        """The projector-off view layer `AMBIENT_LAYER` (structured_light.ambient "scene"): every
        projector collection excluded, the scene's own lights and its world kept. Everything else is
        what a fringe layer holds (a new layer includes every collection, as make_fringe_view_layers'
        do), so by linearity of light its image is what each fringe frame lacks of a capture in the
        lit hall: the fringe call adds it to every frame (core/structured_light.py). Only the combined
        pass, `samples` paths, no denoising; switched off (`use`) for every call but the fringes'."""
        if not self.collections:
            raise DataPipeError("Projector.make_ambient_layer() before build() (fix: build the patterns first)")
        old = self.scene.view_layers.get(AMBIENT_LAYER)
        if old is not None:
            self.scene.view_layers.remove(old)
        vl = self.scene.view_layers.new(AMBIENT_LAYER)
        self.exclude_from(vl)
        _combined_only(vl, samples)
        vl.use = False
        self.ambient_layer_name = vl.name
        return vl

    # -- teardown ---------------------------------------------------------------------------------
    def teardown(self) -> None:
        """Remove every light, light datablock (and its node tree), image, collection and view layer
        this projector made, and the black world override when nothing uses it. Safe to call twice."""
        import bpy

        for name in self.layer_names + ([self.ambient_layer_name] if self.ambient_layer_name else []):
            vl = self.scene.view_layers.get(name)
            if vl is not None and len(self.scene.view_layers) > 1:
                self.scene.view_layers.remove(vl)
        self.layer_names, self.ambient_layer_name = [], None
        for ob in self.lights:
            ld = ob.data
            bpy.data.objects.remove(ob, do_unlink=True)
            if ld is not None and ld.users == 0:
                bpy.data.lights.remove(ld)
        for coll in self.collections:
            bpy.data.collections.remove(coll)
        for img in self.images:
            bpy.data.images.remove(img)
        self.lights, self.collections, self.images = [], [], []
        w = bpy.data.worlds.get(_BLACK_WORLD)
        if w is not None and not any(sc.world == w or any(getattr(vl, "world_override", None) == w
                                                          for vl in sc.view_layers) for sc in bpy.data.scenes):
            bpy.data.worlds.remove(w)


def make_fringe_view_layers(bpy_scene, lights_collections: Sequence, exclude: Iterable = (LIGHTS_COLLECTION,),
                            *, samples: int = 16, strict: bool = True) -> list:
    """One view layer `sl_NN` per projector collection, rendering only that projector's light.

    In layer `sl_NN`: its own collection is included; every other projector collection and every
    collection named in `exclude` (names or Collection objects; missing names are ignored) is
    excluded (`layer_collection.exclude = True`, found at any depth). Only the combined pass is on,
    `samples` Cycles samples, denoising off, a black world override where Blender has one. Every
    other (pre-existing) view layer gets all projector collections excluded. With `strict`, a light
    object still visible in a fringe layer besides its own projector, or an emitting world with no
    black override, raises DataPipeError (see `fringe_layer_leaks`).
    Existing layers of the same name are replaced. Returns the new layers in pattern order."""

    proj_names = [c.name for c in lights_collections]
    excl_names = [getattr(c, "name", c) for c in exclude]
    existing = {vl.name for vl in bpy_scene.view_layers}
    fringe_names = [layer_name(i) for i in range(len(proj_names))]
    for name in fringe_names:
        if name in existing:
            bpy_scene.view_layers.remove(bpy_scene.view_layers[name])
    for vl in bpy_scene.view_layers:
        for name in proj_names:
            _set_exclude(vl, name, True)

    black = _black_world()
    layers = []
    for i, name in enumerate(fringe_names):
        vl = bpy_scene.view_layers.new(name)
        vl.use = True
        for other in proj_names:
            _set_exclude(vl, other, other != proj_names[i])
        for other in excl_names:
            _set_exclude(vl, other, True)
        _combined_only(vl, samples)
        if black is not None:
            vl.world_override = black
        layers.append(vl)
    if strict:
        _raise_on_leaks(bpy_scene, layers, lights_collections)
    return layers


def _combined_only(vl, samples: int) -> None:
    """A fringe or projector-off layer's settings: the combined pass alone, `samples` paths, no
    denoising, freestyle or motion blur."""
    for attr in dir(vl):
        if attr.startswith("use_pass_") and attr != "use_pass_combined":
            try:
                setattr(vl, attr, False)
            except (AttributeError, TypeError):
                pass
    vl.use_pass_combined = True
    vl.samples = int(samples)
    if hasattr(vl, "cycles") and hasattr(vl.cycles, "use_denoising"):
        vl.cycles.use_denoising = False
    for attr in ("use_freestyle", "use_motion_blur"):
        if hasattr(vl, attr):
            setattr(vl, attr, False)


def fringe_layer_leaks(bpy_scene, layers, lights_collections) -> dict[str, list[str]]:
    """{layer name: [what else would light it]}: light objects other than its own projector, and
    "world" when the layer has no black world override and the scene's world emits.

    Emissive materials on meshes are not detected (DataPipe's parts, bin and floor emit nothing)."""
    out = {}
    world_emits = _world_emits(bpy_scene.world)
    for i, vl in enumerate(layers):
        vl.update()
        own = set(ob.name for ob in lights_collections[i].all_objects)
        bad = [ob.name for ob in vl.objects if ob.type == "LIGHT" and ob.name not in own
               and not ob.hide_render]
        override = getattr(vl, "world_override", None)
        if (_world_emits(override) if override is not None else world_emits):
            bad.append("world")
        if bad:
            out[vl.name] = bad
    return out


def _raise_on_leaks(bpy_scene, layers, lights_collections) -> None:
    leaks = fringe_layer_leaks(bpy_scene, layers, lights_collections)
    if leaks:
        raise DataPipeError("light would leak into the fringe view layers: " + "; ".join(
            f"{vl}: {', '.join(obs)}" for vl, obs in leaks.items()) +
            " (fix: hide those lights from rendering, or set scene.other_objects to 'hide' so a run hides the "
            "open scene's own objects; in code: put them in a collection passed in `exclude`)")


def _world_emits(world) -> bool:
    """Whether a world could add light: a Background node with strength > 0 and a non-black or
    linked colour (no node tree: its colour)."""
    if world is None:
        return False
    nt = world.node_tree
    if nt is None:
        return max(world.color) > 0
    for n in nt.nodes:
        if n.bl_idname == "ShaderNodeBackground":
            col, strength = n.inputs["Color"], n.inputs["Strength"]
            if (strength.is_linked or strength.default_value > 0) and (
                    col.is_linked or max(col.default_value[:3]) > 0):
                return True
    return False


# ------------------------------------------------------------------------------------------------
# helpers

def _build_node_tree(nt, img, scale, location, interpolation, strength) -> None:
    N, L = nt.nodes, nt.links
    emission = next((n for n in N if n.bl_idname == "ShaderNodeEmission"), None)
    out = next((n for n in N if n.bl_idname == "ShaderNodeOutputLight"), None)
    if emission is None:
        emission = N.new("ShaderNodeEmission")
    if out is None:
        out = N.new("ShaderNodeOutputLight")
    if not emission.outputs[0].is_linked:
        L.new(emission.outputs[0], out.inputs["Surface"])
    tc = N.new("ShaderNodeTexCoord")
    sep = N.new("ShaderNodeSeparateXYZ")
    dx = N.new("ShaderNodeMath"); dx.operation = "DIVIDE"
    dy = N.new("ShaderNodeMath"); dy.operation = "DIVIDE"
    comb = N.new("ShaderNodeCombineXYZ")
    mp = N.new("ShaderNodeMapping")
    mp.vector_type = "POINT"
    mp.inputs["Scale"].default_value = scale
    mp.inputs["Location"].default_value = location
    mp.inputs["Rotation"].default_value = (0.0, 0.0, 0.0)
    tex = N.new("ShaderNodeTexImage")
    tex.image = img
    tex.extension = "CLIP"
    tex.interpolation = interpolation
    L.new(tc.outputs["Normal"], sep.inputs[0])
    L.new(sep.outputs["X"], dx.inputs[0]); L.new(sep.outputs["Z"], dx.inputs[1])
    L.new(sep.outputs["Y"], dy.inputs[0]); L.new(sep.outputs["Z"], dy.inputs[1])
    L.new(dx.outputs[0], comb.inputs["X"]); L.new(dy.outputs[0], comb.inputs["Y"])
    L.new(comb.outputs[0], mp.inputs["Vector"])
    L.new(mp.outputs[0], tex.inputs["Vector"])
    L.new(tex.outputs["Color"], emission.inputs["Color"])
    emission.inputs["Strength"].default_value = float(strength)


_BLACK_WORLD = "datapipe_sl_black_world"


def _black_world():
    """A world with a black background for the fringe layers' `world_override` (None where the
    Blender version has no world override; DataPipe's own world has strength 0 anyway)."""
    import bpy

    vl_type = bpy.types.ViewLayer
    if "world_override" not in vl_type.bl_rna.properties:
        return None
    w = bpy.data.worlds.get(_BLACK_WORLD)
    if w is None:
        w = bpy.data.worlds.new(_BLACK_WORLD)
        if not w.node_tree:
            w.use_nodes = True
        bg = next((n for n in w.node_tree.nodes if n.bl_idname == "ShaderNodeBackground"), None)
        if bg is not None:
            bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
            bg.inputs["Strength"].default_value = 0.0
        w.color = (0.0, 0.0, 0.0)
    return w



def _set_exclude(view_layer, collection_name_: str, exclude: bool) -> bool:
    from .scene import find_layer_collection      # bpy-side; this module stays importable without bpy
    lc = find_layer_collection(view_layer.layer_collection, collection_name_)
    if lc is None:
        return False
    lc.exclude = exclude
    return True


def _normalized(matrix) -> np.ndarray:
    """A Blender world matrix as a rigid 4x4 (scale removed)."""
    M = np.array(matrix, dtype=np.float64)
    R = M[:3, :3]
    M[:3, :3] = R / np.linalg.norm(R, axis=0, keepdims=True)
    return M


def _to_matrix(T):
    from mathutils import Matrix

    return Matrix([list(map(float, row)) for row in np.asarray(T)])
