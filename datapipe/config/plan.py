"""What a config will do at run time, derived from its fields: the camera distances, the fringe
images and their memory, the finest fringe on the camera sensor, the fringe mode `auto` picks and
whether quadrature mode packs three images per layer. Read by the validation rules and
by the run (core/structured_light.py, core/preflight.py, cli). No bpy here."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..materials_spec import FILE, values as material_values

if TYPE_CHECKING:                 # annotations only: Config's methods call the rules, not the other way
    from .schema import Config, StructuredLightConfig

FRINGE_SUPERSAMPLE = 2             # fringe render at this factor x the camera resolution, block-averaged
                                   # (core/structured_light.py renders at it; fringe_memory_bytes counts it)
SHINY_ROUGHNESS = 0.45             # a visible surface rougher than this scatters like a diffuse one
                                   # (core/structured_light.py: sharp glossy fringes below it)
GREY_CHROMA = 0.1                  # (max - min) / max of a base colour that still packs (grey_materials)


def builds_row_code(sl: "StructuredLightConfig", fringe_mode: str) -> bool:
    """Whether the structured-light camera builds the global reflection filter's row code: the
    patterns carry every light path (`fringe_mode`, resolved: "render" or "quadrature") and
    reflection_filter is "auto" (rendered on shiny renders) or "global" (every render)."""
    return fringe_mode in ("render", "quadrature") and sl.reflection_filter in ("auto", "global")


def _fringe_frames(cfg: Config) -> int:
    """Fringe images per render: F*N, plus the row code (N) where the global reflection filter may
    run (an upper bound: fringe_mode "auto" may resolve to render)."""
    s = cfg.structured_light
    rows = s.steps if builds_row_code(s, "fast" if s.fringe_mode == "fast" else "render") else 0
    return len(s.periods) * s.steps + rows


def fringe_memory_bytes(cfg: Config) -> int:
    """Peak memory of one render's fringe work: every pattern as a float RGBA Blender image plus the
    rendered stack read back at FRINGE_SUPERSAMPLE x the camera resolution (float32) and its mean;
    with `hdr`, the fused float32 stack and one exposure's sensor output besides; with ambient
    "scene", the projector-off image read back and its mean."""
    (Wp, Hp), (W, H) = cfg.projector.resolution, cfg.camera.resolution
    ss = FRINGE_SUPERSAMPLE
    hdr = 8 * W * H if cfg.structured_light.hdr else 0
    ambient = W * H * ss * ss * 4 + W * H * 4 if cfg.structured_light.ambient == "scene" else 0   # projector-off layer
    return _fringe_frames(cfg) * (Wp * Hp * 16 + W * H * ss * ss * 4 + W * H * 4 + hdr) + ambient


def fringe_period_camera_px(cfg: Config) -> float:
    """Predicted finest fringe period in camera pixels, the worst camera pose.

    One projector pixel at distance d is d * sensor_p / (f_p * W_p) metres wide; the camera sees a
    length L at distance d' as L * fx_cam / d' pixels. In camera-object axes the camera looks down
    -Z, so a projector at z_p > 0 sits behind the camera: d = d' + z_p for a part d' in front of
    the camera. Distances d' are from each camera pose to the drop zone centre."""
    from ..geometry import camera_intrinsics, projector_intrinsics
    c, pr, sl = cfg.camera, cfg.projector, cfg.structured_light
    fx_cam = float(camera_intrinsics(c)[0, 0])          # camera.intrinsics when given (a calibration)
    fringe_proj_px = pr.resolution[0] / max(sl.periods)
    metres_per_proj_px = (1.0 / float(projector_intrinsics(cfg)[0, 0]) if pr.intrinsics is not None
                          else pr.sensor_width / (pr.focal_length * pr.resolution[0]))   # at 1 m
    worst = math.inf
    for d in camera_distances(cfg):
        d_cam = max(d, c.clip_start)
        d_proj = max(d_cam + pr.location[2], c.clip_start)
        worst = min(worst, fringe_proj_px * metres_per_proj_px * d_proj * fx_cam / d_cam)
    return worst


def camera_distances(cfg: Config) -> list[float]:
    """Camera-to-bin distances a run can render from (m): each pool pose to the drop zone centre, or
    the bin_view sampler's distance range."""
    c = cfg.camera
    if c.sampler.kind == "bin_view":
        return [float(d) for d in c.sampler.distance]
    return [math.dist(p.location, cfg.scene.drop_zone_loc) for p in c.poses] or [1.0]


def resolve_fringe_mode(cfg) -> str:
    """`structured_light.fringe_mode` with "auto" decided from the configured materials:
    "quadrature" when any of them (bin, or any choice of any object entry) has roughness below
    SHINY_ROUGHNESS, since only path-traced light carries the fringes that shiny parts mirror
    (ghosts, holes) and the quadrature basis path-traces all of it at 1 + 2F instead of F x N
    images (sl/fringe_basis.py: the same frames as "render", path for path;
    benchmarks/results/sl_glossy_modes.md); "render" instead with a projector gamma (its patterns
    are no mix of cos and sin); "fast" otherwise, where fast and render agree (sl_fringe_modes.md).
    reflection_filter "global" needs a path-traced row code: never "fast". Materials that come
    from the mesh file ("file") count as diffuse: set "quadrature" for meshes that carry shiny
    materials."""
    mode = cfg.structured_light.fringe_mode
    if mode != "auto":
        return mode
    traced = "quadrature" if float(cfg.structured_light.projector_gamma) == 1.0 else "render"
    if cfg.structured_light.reflection_filter == "global":   # its row code must be path-traced
        return traced
    shiny = any(spec != FILE and float(material_values(spec)["roughness"]) < SHINY_ROUGHNESS
                for spec in configured_materials(cfg))
    return traced if shiny else "fast"


def _listed(spec) -> list:
    """A material field's choices: a list draws one per scene or part, anything else is one."""
    return list(spec) if isinstance(spec, list) else [spec]


def _object_materials(cfg) -> list:
    return [s for entry in cfg.objects for s in _listed(entry.material)]


def configured_materials(cfg) -> list:
    """Every material a config can put in a scene: the bin's, and each choice of each object entry."""
    return _listed(cfg.scene.bin_material) + _object_materials(cfg)


def grey_materials(cfg) -> bool:
    """Whether quadrature mode may pack three basis images per layer (sl.pack_basis): every
    configured material's base colour within GREY_CHROMA of grey ((max - min) / max of its R, G,
    B; `variation` scales all three alike). Packing takes an image back from one colour channel by
    its ratio to the white image in that channel; where light of different colours mixes in a
    pixel that ratio is weighted by colour, not by grey (sl/fringe_basis.py). Measured on a mirror
    plate beside a lit wall (tests/blender/test_fringe_quadrature.py): steel's tint (0.075) moves
    the frames by at most 0.2% of the peak, a copper plate mirroring a red wall by up to 9%;
    steel parts in a blue bin decode with median +19% and p99 +7% against render mode
    (benchmarks/results/sl_glossy_modes.md). Mesh file materials ("file") may carry any colour:
    not packed (the bin's "file" is grey). Drawn textures (scene.textures) are grey only with
    saturation 0 and no image sets (an image's colours may be any)."""
    tex = cfg.scene.textures
    if tex.targets and ("image" in tex.kinds or max(float(v) for v in tex.saturation) > 0):
        return False
    bin_specs = [s for s in _listed(cfg.scene.bin_material) if s != FILE]   # the bin's "file": built-in grey
    for spec in bin_specs + _object_materials(cfg):
        if spec == FILE:
            return False
        rgb = [float(c) for c in material_values(spec)["base_color"][:3]]
        if max(rgb) > 0 and (max(rgb) - min(rgb)) / max(rgb) > GREY_CHROMA:
            return False
    return True
