"""`Scene.datapipe.structured_light`: fringe patterns, sensor, exposure and decoding
(`Config.structured_light`); the period and HDR lists are typed as text."""
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty
from bpy.types import PropertyGroup

from ... import config as C
from ..convert import format_factors, format_periods, parse_factors, parse_periods
from .fields import default, enum_choices


_L = C.StructuredLightConfig
_FIXED_EXPOSURE = 0.5        # the Exposure field's value while Auto Exposure is on (the former default)


def _list_text(name: str, parse, fmt, hint: str):
    """Getter and setter of a list typed as text (stored normalised in the hidden `<name>_text`)."""
    def get(self):
        return getattr(self, f"{name}_text")

    def set_(self, value):
        try:
            setattr(self, f"{name}_text", fmt(parse(value)))
        except ValueError as e:        # keep the last valid list; the field shows it again
            print(f"DataPipe: structured_light.{name}: ignored {value!r} ({e}); {hint}")
    return get, set_


_get_periods, _set_periods = _list_text("periods", parse_periods, format_periods, "give integers >= 1, e.g. '1, 8, 64'")
_get_hdr, _set_hdr = _list_text("hdr", parse_factors, format_factors,
                                "give factors > 0, e.g. '0.25, 1, 4', 'auto', or nothing for one exposure")


def _sensor_search(self, context, edit_text):
    """Suggestions for the sensor field, read when the field is edited (datapipe.sl imports scipy:
    too slow for add-on registration). Unknown names are reported by Config.validate()."""
    try:
        from ...sl.sensor import PRESETS
    except ImportError:
        return []
    return [name for name in sorted(PRESETS) if edit_text.lower() in name.lower()]


class DATAPIPE_PG_structured_light(PropertyGroup):
    enabled: BoolProperty(name="Structured Light", description="Render phase-shifted fringe images lit by "
                          "the projector and decode a structured-light depth map per render",
                          default=default(_L, "enabled"))
    periods_text: StringProperty(default=format_periods(default(_L, "periods")), options={"HIDDEN"})
    periods: StringProperty(
        name="Periods", description="Fringe periods across the projector width, coarse to fine, comma "
        "separated (e.g. '1, 8, 64' hierarchical, '8, 7' heterodyne, '13, 7' or '9, 10, 11' number-theoretic)",
        get=_get_periods, set=_set_periods)
    steps: IntProperty(name="Steps", description="Phase steps per period (4 or more avoids gamma errors)",
                       default=default(_L, "steps"), min=3, soft_max=16)
    unwrap: EnumProperty(name="Unwrapping", description="Temporal phase unwrapping method",
                         items=enum_choices(C.UNWRAP_METHODS), default=default(_L, "unwrap"))
    fringe_mode: EnumProperty(name="Fringe Mode", description="fast: one render with the projector showing white, "
                              "every fringe image synthesised from it (exact direct light, bounce light as offset); "
                              "render: every fringe image path-traced (the reference, needed for mirrored fringes on shiny parts); "
                              "quadrature: a white, a cosine and a sine image per period path-traced, every phase step mixed "
                              "from them (the same light as render, 7 images instead of 12, three per rendered layer when every material is grey); "
                              "auto: quadrature when a configured material is shiny (render with a projector gamma), else fast",
                              items=enum_choices(C.FRINGE_MODES), default=default(_L, "fringe_mode"))
    samples: IntProperty(name="Samples", description="Render paths per camera pixel for each fringe image (point-sampled at 2x2 per pixel; 4 is enough once bounce light is blurred, see docs/SL_SETTINGS.md)",
                         default=default(_L, "samples"), min=1, soft_max=4096)
    sensor: StringProperty(name="Sensor Model", description="Camera noise model preset (datapipe.sl.sensor: "
                           "shot and read noise, ADC bits, saturation), e.g. ideal, industrial",
                           default=default(_L, "sensor"), search=_sensor_search)
    auto_exposure: BoolProperty(name="Auto Exposure", description="Meter each render's fringes and set the "
                                "exposure so the brightest lit pixels reach 80% of the full well (like a real "
                                "scanner's auto exposure); off: the fixed Exposure below",
                                default=default(_L, "exposure") == "auto")
    exposure: FloatProperty(name="Exposure", description="Fixed scale on the linear radiance before the sensor "
                            "model (used when Auto Exposure is off)", min=1e-6, soft_max=10.0,
                            default=_FIXED_EXPOSURE)
    hdr_text: StringProperty(default=format_factors(default(_L, "hdr")), options={"HIDDEN"})
    hdr: StringProperty(name="HDR Factors", description="Relative exposure factors fused per pixel, e.g. "
                        "'0.25, 1, 4' (metal parts); 'auto': shorter exposures added per render while "
                        "highlights clip; empty: one exposure", get=_get_hdr,
                        set=_set_hdr)
    reflection_filter: EnumProperty(name="Reflection Filter", description="local: drop pixels whose fringe "
                                    "frequencies disagree in modulation (light of two paths); global: also render a "
                                    "row code and drop mirror ghosts (+Steps path-traced images); auto: global on "
                                    "renders with shiny surfaces, else local; off",
                                    items=enum_choices(C.REFLECTION_FILTERS), default=default(_L, "reflection_filter"))
    ambient: EnumProperty(name="Ambient Light", description="scene: the scene's own lights (key light, world) "
                          "also reach the fringe images, as a hall light on a real scanner (more shot noise, "
                          "clipping, dark parts lost; one more layer in the fringe render); off: the projector alone",
                          items=enum_choices(C.AMBIENT_MODES), default=default(_L, "ambient"))
    debug: BoolProperty(name="Debug Maps", description="Also write wrapped/absolute phase, modulation and "
                        "reason codes", default=default(_L, "debug"))
    projector_gamma: FloatProperty(name="Projector Gamma", description="Projector response exponent (it emits "
                                   "pattern ** gamma; 1 = linear); the decoder corrects the phase ripple",
                                   min=0.2, max=5.0, default=default(_L, "projector_gamma"))
