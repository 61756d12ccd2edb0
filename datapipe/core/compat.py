"""Every bpy 4.2 .. 5.x difference DataPipe relies on, in one place.

Callers never test `bpy.app.version` themselves: they call these helpers. Each fact here was
observed by running both bpy 4.2.0 and 5.0.1; where only 5.0.1 could be re-checked in this
repository's venv, the 4.2 branch follows what was observed on 4.2.0 then (noted at each helper).

Topics: engine ids, the compositor node tree and its sink (Composite vs. Group Output), the File
Output node (paths, items, multilayer 32-bit EXR, the file name it writes), Render Layers socket
names, the Cycles device, the denoiser's settings and sampling pattern, colour management.
"""
from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path
from typing import Iterable

import bpy

from ..io.files import scratch_dir

VERSION: tuple[int, int, int] = tuple(bpy.app.version)
IS_5 = VERSION >= (5, 0, 0)

# ------------------------------------------------------------------------------------------------
# engines

EEVEE = "BLENDER_EEVEE" if IS_5 else "BLENDER_EEVEE_NEXT"


def engine_id(name: str) -> str:
    """Config engine name -> this Blender's engine id ("EEVEE" spellings differ between 4.2 and 5.0)."""
    if name.upper() in ("EEVEE", "BLENDER_EEVEE", "BLENDER_EEVEE_NEXT"):
        return EEVEE
    return name.upper()


# ------------------------------------------------------------------------------------------------
# compositor tree

COMPOSITOR_TREE_NAME = "datapipe_compositor"


def compositor_tree(scene, *, clear: bool = True):
    """The scene's compositor node tree, created if missing; emptied when `clear`.

    5.x: `scene.compositing_node_group` (a CompositorNodeTree data-block; `scene.node_tree` is
    gone). 4.2: `scene.use_nodes = True; scene.node_tree` (comes with Composite + Render Layers).
    """
    if IS_5:
        tree = scene.compositing_node_group
        if tree is None:
            tree = bpy.data.node_groups.new(COMPOSITOR_TREE_NAME, "CompositorNodeTree")
            scene.compositing_node_group = tree
    else:
        scene.use_nodes = True
        tree = scene.node_tree
    if clear:
        tree.nodes.clear()
        if IS_5:
            for item in list(tree.interface.items_tree):
                tree.interface.remove(item)
    scene.render.use_compositing = True
    return tree


def add_compositor_sink(tree, image_socket):
    """Route `image_socket` to the compositor's result (the Render Result / viewer image).

    5.x: a Group Output node with an "Image" colour interface socket; 4.2: a Composite node.
    Returns the sink node.
    """
    if IS_5:
        if tree.interface.items_tree.get("Image") is None:
            tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        sink = tree.nodes.new("NodeGroupOutput")
    else:
        sink = tree.nodes.new("CompositorNodeComposite")
    sink.name = sink.label = "datapipe_sink"
    tree.links.new(image_socket, sink.inputs["Image"])
    return sink


def render_layers_node(tree, scene, view_layer_name: str, name: str | None = None):
    """A Render Layers node reading `view_layer_name` of `scene`."""
    rl = tree.nodes.new("CompositorNodeRLayers")
    rl.scene = scene
    rl.layer = view_layer_name
    if name:
        rl.name = rl.label = name
    return rl


# Render Layers output socket names per pass; 5.0 renamed "IndexOB" to "Object Index".
_RL_SOCKETS = {
    "image": ("Image",),
    "alpha": ("Alpha",),
    "depth": ("Depth",),
    "normal": ("Normal",),
    "index": ("Object Index", "IndexOB"),
}


def rl_socket(rl, kind: str):
    """The Render Layers output for a pass kind ('image', 'alpha', 'depth', 'normal', 'index').

    The pass must be enabled on the view layer first, or the socket is hidden (KeyError)."""
    names = _RL_SOCKETS.get(kind, (kind,))
    for n in names:
        s = rl.outputs.get(n)
        if s is not None and s.enabled:
            return s
    raise KeyError(f"Render Layers node {rl.name!r} has no enabled output {names} "
                   f"(is the pass enabled on view layer {rl.layer!r}?)")


# ------------------------------------------------------------------------------------------------
# File Output node: one multilayer 32-bit EXR per render

def _set_multilayer_exr(fmt) -> None:
    if IS_5:
        fmt.media_type = "MULTI_LAYER_IMAGE"      # must precede file_format on 5.x
    fmt.file_format = "OPEN_EXR_MULTILAYER"
    fmt.color_depth = "32"
    fmt.exr_codec = "ZIP"


def new_file_output(tree, directory: str | os.PathLike, basename: str, name: str = "datapipe_file_output"):
    """A File Output node writing one multilayer float32 EXR; starts with no inputs.

    Braces are path templates on 5.x (a silent skip of the write), so they are refused here."""
    fo = tree.nodes.new("CompositorNodeOutputFile")
    fo.name = fo.label = name
    _set_multilayer_exr(fo.format)
    if IS_5:
        if hasattr(fo, "save_as_render"):
            fo.save_as_render = False             # write scene-linear data, never view-transformed
    else:
        fo.layer_slots.clear()
    set_file_output_path(fo, directory, basename)
    return fo


def set_file_output_path(fo, directory: str | os.PathLike, basename: str) -> None:
    """Where the File Output node writes `basename`: in `directory`, or, for a folder inside a
    run's output folder, in the run's private scratch folder reached through its handle
    (datapipe/io/guard.py): Blender writes by path, and a link put in the output folder during the
    render must not lead its write elsewhere. written_files and take_written_exr look there too."""
    directory = scratch_dir(directory)
    path = os.path.join(os.fspath(directory), basename)
    if "{" in path or "}" in path:
        raise ValueError(f"braces are path templates in Blender 5 and would skip the write: {path!r}")
    if IS_5:
        fo.directory = os.fspath(directory) + os.sep
        fo.file_name = basename
    else:
        fo.base_path = path


def file_output_add_input(fo, name: str, socket_type: str):
    """Add an input layer `name` (socket_type 'FLOAT', 'VECTOR' or 'RGBA'); returns its socket.

    In the multilayer EXR its channels are "<name>.V" (FLOAT), "<name>.X/Y/Z" (VECTOR) or
    "<name>.R/G/B/A" (RGBA)."""
    if IS_5:
        fo.file_output_items.new(socket_type, name)
    else:
        fo.layer_slots.new(name)
    return fo.inputs[name]


_FRAME_SUFFIX = re.compile(r"^\d*$")


def written_files(directory: str | os.PathLike, basename: str) -> list[Path]:
    """Multilayer EXRs the File Output node wrote for `basename` in `directory`.

    5.x writes `<basename>.exr`; 4.2 appends the frame number, `<basename>0001.exr`. Both match."""
    d = scratch_dir(directory)
    if not d.is_dir():
        return []
    out = []
    for p in d.iterdir():
        if p.suffix.lower() == ".exr" and p.name.startswith(basename):
            if _FRAME_SUFFIX.match(p.name[len(basename):-len(p.suffix)]):
                out.append(p)
    return sorted(out)


def take_written_exr(directory: str | os.PathLike, basename: str, what: str = "pass",
                     expect: Iterable[str] = ()) -> dict:
    """Read the EXR the File Output node just wrote for `basename`, delete it, return its channels.

    Blender reports no write error (a full disk leaves no file, a truncated one, or one without
    some layers), so each of those is an OSError naming the file (exit status 1), never a wrong
    preset: no file, an unreadable file (exr.read_exr), or one lacking a channel of `expect`."""
    from ..io.exr import read_exr, unreadable
    from ..io.files import disk_full_error
    written = written_files(directory, basename)
    if not written:
        raise disk_full_error(Path(directory) / f"{basename}.exr", f"Blender wrote no {what} file")
    newest = max(written, key=lambda p: p.stat().st_mtime)
    try:
        channels = read_exr(newest)
        missing = sorted(set(expect) - set(channels))
        if missing:
            raise unreadable(newest, f"Blender's {what} file lacks {', '.join(missing[:4])}"
                                     f"{' ...' if len(missing) > 4 else ''}")
    except OSError as e:                   # a file cut short: says "disk full" when the disk is (before freeing it)
        raise disk_full_error(newest, e.strerror or str(e)) from None
    finally:
        for p in written:
            p.unlink(missing_ok=True)
    return channels


# ------------------------------------------------------------------------------------------------
# Cycles device, colour management

GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")   # tried in this order (OptiX: NVIDIA RTX)
_gpu_fallback_reported = False


def set_cycles_device(scene, device: str) -> str:
    """Put Cycles on the CPU, or (`device` "GPU") on the first backend in GPU_BACKENDS that has a
    device, with all that backend's devices enabled. Returns what renders: "CPU" or the backend.

    No GPU: Cycles renders on the CPU, and the first time in a process this prints one line on
    stderr saying so (a dataset is still made; a "GPU" config stays usable on laptops and CI)."""
    global _gpu_fallback_reported
    if device != "GPU":
        scene.cycles.device = "CPU"
        return "CPU"
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for backend in GPU_BACKENDS:
        try:
            prefs.compute_device_type = backend
        except TypeError:              # this Blender build has no such backend
            continue
        prefs.get_devices()
        gpus = [d for d in prefs.devices if d.type == backend]
        if gpus:
            for d in prefs.devices:
                d.use = d.type == backend
            scene.cycles.device = "GPU"
            return backend
    prefs.compute_device_type = "NONE"
    scene.cycles.device = "CPU"
    if not _gpu_fallback_reported:
        _gpu_fallback_reported = True
        import sys
        print("datapipe: render.device is GPU, but Cycles finds no GPU device (tried "
              f"{', '.join(GPU_BACKENDS)}): rendering on the CPU (set render.device to \"CPU\" to "
              "silence this)", file=sys.stderr, flush=True)
    return "CPU"


def set_denoiser_settings(cy, prefilter: str, quality: str) -> None:
    """OpenImageDenoise's prefilter and quality on `scene.cycles` (render.denoise_prefilter,
    render.denoise_quality). Both enums are in bpy 5.0.1 (prefilter NONE / FAST / ACCURATE, quality
    HIGH / BALANCED / FAST, read back in tests/blender/test_renderer.py). The quality was set only
    where the build has it (`hasattr`, as before this helper) and 4.2.0 could not be re-checked here:
    a build without it renders HIGH's network, so any other quality asked of it is refused."""
    cy.denoising_prefilter = prefilter
    if hasattr(cy, "denoising_quality"):
        cy.denoising_quality = quality
    elif quality != "HIGH":
        from ..errors import ConfigError, Problem
        raise ConfigError(Problem("render.denoise_quality", f"this Blender ({bpy.app.version_string}) has no "
                                  "OpenImageDenoise quality setting",
                                  'use "HIGH", or a Blender that has it (bpy 5.0.1 does)'))


@contextlib.contextmanager
def sampling_pattern(cy, pattern: str):
    """Cycles' sampling pattern `pattern` on `scene.cycles` for the calls inside, the scene's own
    after them (render.sampling_pattern; "SCENE": the scene's own throughout, nothing set). bpy
    5.0.1 offers AUTOMATIC, TABULATED_SOBOL and BLUE_NOISE (read back in tests/blender/
    test_renderer.py); a build that lacks the one asked for is refused, naming the field and what
    the build offers."""
    if pattern == "SCENE":
        yield
        return
    own = cy.sampling_pattern
    try:
        cy.sampling_pattern = pattern
    except TypeError as e:             # bpy: enum "X" not found in (...)
        from ..errors import ConfigError, Problem
        raise ConfigError(Problem("render.sampling_pattern", f"this Blender ({bpy.app.version_string}) has no "
                                  f"sampling pattern {pattern!r}: {e}", 'use "SCENE" or one it lists')) from None
    try:
        yield
    finally:
        cy.sampling_pattern = own


def set_linear_color_management(scene) -> None:
    """View transform Standard, no look, exposure 0, gamma 1, no curves, dither 0 (same ids in 4.2/5.x)."""
    scene.display_settings.display_device = "sRGB"
    vs = scene.view_settings
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    vs.use_curve_mapping = False
    scene.render.dither_intensity = 0.0
