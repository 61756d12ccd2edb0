"""What a config will do at run time, derived from its fields: the camera distances, the fringe
images and their memory, the finest fringe on the camera sensor, the fringe mode `auto` picks and
whether quadrature mode packs three images per layer, and `FringePlan`, all of the structured-light
camera's decisions made once per run (the camera builds its fringe strategy from it, `validate`
prints it). Read by the validation rules and by the run (core/structured_light.py,
core/preflight.py, cli). No bpy here."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..materials_spec import FILE, values as material_values

if TYPE_CHECKING:                 # annotations only: Config's methods call the rules, not the other way
    from ..sl.unwrap import UnwrapPlan
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


def layer_samples(samples: int, supersample: int) -> int:
    """Cycles paths per point sample of a fringe layer: `samples` counts paths per camera pixel,
    which holds supersample x supersample point samples (at least one path each)."""
    return max(1, int(math.ceil(int(samples) / int(supersample) ** 2)))


@dataclass(frozen=True)
class QuadCall:
    """One Cycles call of quadrature mode: white + a (cos, sin) pair per period across the width
    (`periods`) and per row period over the height (`rows`), at `supersample` x the camera grid."""
    periods: tuple
    rows: tuple
    supersample: int


def quad_call_layers(call: QuadCall, packed: bool, rows: bool = True) -> int:
    """View layers of a quadrature call: its basis images one per layer, or `packed` three to a
    layer (sl.packed_layout); its row-code layers, which come last, only with `rows`."""
    from ..sl.fringe_basis import basis_size, packed_layout
    n_rows = len(call.rows) if rows else 0
    if packed:
        return len(packed_layout(len(call.periods), n_rows))
    return basis_size(len(call.periods), rows=bool(n_rows))


@dataclass(frozen=True)
class FringePlan:
    """What the structured-light camera does in a run, decided once from the Config (`from_config`):
    the fringe mode (`auto` resolved), the strategy's variant (quadrature packing, its coarse grid;
    fast mode's bounce layers), the images per set (F x N, the row code), the Cycles calls and their
    layers, the unwrap plan, the samples and the memory. core/structured_light.py builds its fringe
    strategy from it; `validate` prints `describe()`. Tests and benchmarks choose a variant by
    `from_config`'s arguments."""
    mode: str                     # "render" | "quadrature" | "fast": structured_light.fringe_mode, "auto" resolved
    requested: str                # structured_light.fringe_mode as written
    periods: tuple                # fringe frequencies K, in stack order
    steps: int                    # phase steps N per frequency
    samples: int                  # paths per camera pixel of the fringe layers
    supersample: int              # point-sample grid: supersample x the camera resolution (FRINGE_SUPERSAMPLE)
    packed: bool                  # quadrature: three basis images per layer, one per colour channel
    grey: bool                    # every configured material is grey (grey_materials: what packing needs)
    coarse_supersample: int       # quadrature: the coarse periods' grid (= supersample: one call, the shipped one)
    bounce_min_gain: float | None  # fast: periods whose bounce keeps this modulation get bounce layers (None: default)
    row_periods: tuple            # the global reflection filter's row code (empty: none built)
    reflection_filter: str
    ambient: bool                 # structured_light.ambient "scene": the projector-off layer
    projector_gamma: float
    exposure: object              # structured_light.exposure and .hdr, as `validate` prints them
    hdr: object
    unwrap: "UnwrapPlan"          # sl.plan_unwrap of the periods: how the decoder unwraps them
    memory_bytes: int             # fringe_memory_bytes: one render's fringe work at most

    @classmethod
    def from_config(cls, cfg: Config, *, packed: bool | None = None, coarse_supersample: int | None = None,
                    bounce_min_gain: float | None = None) -> "FringePlan":
        """The plan of `cfg`. Variants `auto` never picks, for tests and benchmarks: `packed`
        (quadrature: force three images per layer, or one, whatever the materials),
        `coarse_supersample` (quadrature: 1 renders the coarse periods in a second call at the
        camera grid, benchmarks/results/sl_glossy_modes.md), `bounce_min_gain` (fast mode's bounce
        layers, core/fringe_fast.py). ValueError for periods the decoder cannot unwrap."""
        from ..sl.scanner import ROW_PERIODS
        from ..sl.unwrap import plan_unwrap
        s = cfg.structured_light
        mode = resolve_fringe_mode(cfg)
        grey = grey_materials(cfg)
        return cls(
            mode=mode, requested=s.fringe_mode, periods=tuple(s.periods), steps=int(s.steps), samples=int(s.samples),
            supersample=FRINGE_SUPERSAMPLE, grey=grey,
            packed=mode == "quadrature" and (grey if packed is None else bool(packed)),
            coarse_supersample=FRINGE_SUPERSAMPLE if coarse_supersample is None else int(coarse_supersample),
            bounce_min_gain=bounce_min_gain,
            row_periods=tuple(ROW_PERIODS) if builds_row_code(s, mode) else (),
            reflection_filter=s.reflection_filter, ambient=s.ambient == "scene",
            projector_gamma=float(s.projector_gamma), exposure=s.exposure,
            hdr=s.hdr if isinstance(s.hdr, str) else tuple(s.hdr),
            unwrap=plan_unwrap(s.periods, s.unwrap), memory_bytes=fringe_memory_bytes(cfg))

    @property
    def n_fringe(self) -> int:
        """Images of the column-coded fringes per set: F x N."""
        return len(self.periods) * self.steps

    @property
    def row_code(self) -> bool:
        """Whether the row code is built (rendered on the renders that need it)."""
        return bool(self.row_periods)

    @property
    def row_images(self) -> int:
        """Images of the row code after the fringe images (0 without one)."""
        return len(self.row_periods) * self.steps

    @property
    def layer_samples(self) -> int:
        return layer_samples(self.samples, self.supersample)

    def quad_calls(self) -> list[QuadCall]:
        """Quadrature mode's Cycles calls. All in one call on the render mode's point grid when
        `coarse_supersample` equals `supersample` (the shipped plan: the same paths as render mode,
        so the same frames, float rounding aside); else the finest period (the depth) and the row
        code (the reflection filter) there, and the coarse periods (fringe orders only) in a second
        call at `coarse_supersample`."""
        if self.coarse_supersample == self.supersample or len(self.periods) == 1:
            return [QuadCall(self.periods, self.row_periods, self.supersample)]
        fine = max(self.periods)
        return [QuadCall((fine,), self.row_periods, self.supersample),
                QuadCall(tuple(K for K in self.periods if K != fine), (), self.coarse_supersample)]

    def describe(self) -> list[str]:
        """What the structured-light camera will do, as `validate` tells it: the fringe mode (with
        why, for "auto"), the images per render, the exposure and the reflection filter."""
        images = f"{self.n_fringe} fringe images"
        if self.row_code:
            images += f" (+{self.row_images} row code{' on shiny renders' if self.reflection_filter == 'auto' else ''})"
        if self.mode == "quadrature":
            basis = sum(1 + 2 * len(c.periods) for c in self.quad_calls())
            images += (f", mixed from {basis} rendered images (white + cos, sin per period"
                       f"{'; +2 for the row code' if self.row_code else ''})")
            if self.packed:
                layers = sum(quad_call_layers(c, True) for c in self.quad_calls())
                images += f", three per Cycles layer: {layers} layers" + (" (every material is grey)" if self.grey else "")
            else:
                images += (", one per Cycles layer (a material has a colour or comes from its mesh file: three "
                           "per layer would mix its colours)" if not self.grey else ", one per Cycles layer")
        paths = self.layer_samples * self.supersample ** 2
        if paths != self.samples:       # at least one path per point sample: 1-3 render what 4 does
            images += (f", {paths} Cycles paths per camera pixel (samples {self.samples} rounded up: one path "
                       f"or more per point of the {self.supersample} x {self.supersample} grid)")
        hdr = f", HDR {self.hdr if isinstance(self.hdr, str) else list(self.hdr)}" if self.hdr else ""
        return [f"fringe mode {self.mode}{self._why()}", images, f"exposure {self.exposure}{hdr}",
                f"reflection filter {self.reflection_filter}"]

    def _why(self) -> str:
        """Why "auto" chose the mode ("" when fringe_mode names it)."""
        if self.requested != "auto":
            return ""
        shiny = ("a configured material is shiny" if self.reflection_filter != "global"
                 else "reflection_filter global needs a path-traced row code")
        return {"quadrature": f" (auto: {shiny}; quadrature path-traces every light path at 1 + 2F images, "
                              "as render does at F x N)",
                "render": f" (auto: {shiny}, and projector_gamma {self.projector_gamma:g} rules out quadrature)",
                "fast": " (auto: every configured material is diffuse)"}[self.mode]
