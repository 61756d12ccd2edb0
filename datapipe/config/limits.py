"""What a Config field may hold: the choices of the string fields and the upper limits beyond
which a preset is a typo, not a dataset. Read by the schema (defaults), the parser and the rules."""

SCHEMA_VERSION = 1

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
OUTPUT_KINDS = ("rgb", "depth", "normals", "mask", "object_coords",   # object_coords: only when listed
                "sl_gray", "point_cloud")      # the scanner's grey image and organised cloud: need structured light
SL_OUTPUT_KINDS = ("sl_gray", "point_cloud")
FORMATS = ("native", "bop")
ENGINES = ("CYCLES",)
DEVICES = ("CPU", "GPU")
# render.denoise_prefilter / render.denoise_quality: Cycles' OpenImageDenoise settings, by their
# Cycles names (scene.cycles.denoising_prefilter / denoising_quality); the first is the default
DENOISE_PREFILTERS = ("ACCURATE", "FAST", "NONE")
DENOISE_QUALITIES = ("HIGH", "BALANCED", "FAST")
# render.sampling_pattern: "SCENE" leaves scene.cycles.sampling_pattern as the scene has it (a new
# scene: TABULATED_SOBOL); the others are Cycles' names for it in bpy 5.0.1
SAMPLING_PATTERNS = ("SCENE", "TABULATED_SOBOL", "BLUE_NOISE", "AUTOMATIC")
# AUTO: DECOMPOSED for clearly concave meshes, else CONVEX_HULL. DECOMPOSED and MESH: a compound of
# convex pieces (Blender's moving triangle meshes threw concave parts out; see collision.py)
ORIGINS = ("file", "bbox_center")       # objects[i].origin
COLLISION_SHAPES = ("AUTO", "DECOMPOSED", "MESH", "CONVEX_HULL", "BOX", "SPHERE", "CAPSULE", "CYLINDER", "CONE")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")
UNWRAP_METHODS = ("auto", "heterodyne", "multi-frequency", "number-theoretic")   # datapipe.sl.unwrap
SAMPLER_KINDS = ("pool", "bin_view")
PICK_ORDERS = ("top", "visible", "random")   # scene.picks.order (datapipe/draws/picks.py)
FRINGE_MODES = ("auto", "fast", "quadrature", "render")   # structured_light.fringe_mode (core/fringe_fast.py,
                                            # sl/fringe_basis.py); auto: quadrature when a configured material
                                            # is shiny (render with a projector gamma), else fast
REFLECTION_FILTERS = ("auto", "local", "global", "off")
AMBIENT_MODES = ("off", "scene")          # structured_light.ambient (core/fringe_ambient.py)
TEXTURE_TARGETS = ("bin", "floor", "parts")     # scene.textures.targets (draws/textures.py)
TEXTURE_KINDS = ("noise", "voronoi", "wave", "brick", "checker", "image")   # scene.textures.kinds
OTHER_OBJECTS = ("auto", "hide", "keep")   # scene.other_objects (core/scene.py)   # structured_light.reflection_filter (sl/filters.py)
MAX_RESOLUTION = 8192
# The sidebar holds what validate() accepts, and validate() refuses what the sidebar cannot hold, with one
# message for both (the add-on's Load Preset runs validate() first): Blender's IntProperty is a signed
# 32-bit integer and its FloatProperty a float32, so integer fields end at MAX_INT32 and fields that
# must be > 0 start at these smallest values (the sidebar properties' `min`, ui/props/).
MAX_INT32 = 2**31 - 1              # scene.seed, objects[i].obj_id
MIN_POSITIVE = {                   # field (objects[i] as "objects") -> smallest value; unit
    "scene.drop_zone_scale": 1e-4,         # m, half extent (0.1 mm)
    "scene.bin_wall_thickness": 1e-5,      # m
    "camera.sensor_width": 1e-3,           # mm
    "camera.clip_start": 1e-5,             # m
    "camera.clip_end": 2e-5,               # m (the sidebar keeps clip_end > clip_start by halving/doubling)
    "projector.sensor_width": 1e-3,        # mm
    "projector.power": 1e-6,               # W
    "simulation.settle_speed": 1e-6,       # m/s
    "objects.scale": 1e-6,                 # file units -> m
    "objects.mass": 1e-6,                  # kg (1 mg)
}
# Upper limits: beyond them a preset is a typo, not a dataset (validate() says so before any work).
MAX_RENDERS = 1_000_000            # ~12 days of Cycles at 1 s per render (= seeds.MAX_PLAN_RENDERS)
MAX_SAMPLES = 4096                 # Cycles paths per pixel of the RGB layer
MAX_SL_SAMPLES = 1024              # fringe paths per camera pixel
MAX_STEPS = 32                     # phase steps: noise falls as 1/sqrt(steps); 32 is 2.8x better than 4
MAX_PERIODS = 8                    # fringe frequencies
MAX_INSTANCES = 500                # instances of one object per scene
MAX_FRINGE_BYTES = 16 * 2**30      # one render's fringe patterns + stack (see fringe_memory_bytes)
MAX_FREE_NESTING = 8              # lists/dicts inside a free-form field (a material list of dicts of lists: 3)
MAX_PICKLE_NESTING = 1000          # containers in an input pickle (the original's: 5); hashing a key nested
                                   # ~120,000 deep overflowed CPython's 8 MB C stack (datapipe/config/pickle_depth.py)
MAX_FIELD_OF_VIEW_DEG = 150.0      # camera/projector full angle across the sensor width
MIN_FRINGE_CAMERA_PX = 3.0         # finest fringe period on the camera sensor (sampling limit, > 2)
