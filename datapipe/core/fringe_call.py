"""The pieces both fringe modes share (core/structured_light.py renders every pattern,
core/fringe_fast.py a flat-lit layer and the coarse periods' bounce layers): the isolated Cycles
call that renders only some view layers at the point-sampled sub-pixel grid, and (from
sl.fringe_synth, which the scanner's global-light filter reads too) the modulation a K-period
fringe keeps when bounced light sees it blurred, and the projector-off layer of
structured_light.ambient "scene" (rendered in the fringe call of either mode). Its own module so
that neither mode imports the other."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..io.files import make_dirs
from ..sl.fringe_synth import INDIRECT_BLUR_PX, indirect_gain  # noqa: F401  (the bounce model both modes render)
from ..world import SILENT, Reporter
from .projector import AMBIENT_LAYER


def isolated_render(sc, tree, file_output, layer_names, render_dir, basename, *, seed: int,
                    supersample: int, filter_width: float, what: str = "", progress: Reporter = SILENT) -> float:
    """Render only the view layers `layer_names` of scene `sc` in their own Cycles call, written by
    `file_output` (muted otherwise) to `render_dir`/`basename`, at `supersample` x the resolution
    with pixel filter `filter_width` and Cycles seed `seed`; every other layer and File Output
    node is switched off for the call and everything is restored afterwards. `what`: the progress
    line's words for what it renders, reported to `progress` (the renderer's). Returns wall seconds."""
    import bpy
    from . import compat

    render_dir = Path(render_dir)
    make_dirs(render_dir)          # never through a link in the output folder
    for stale in compat.written_files(render_dir, basename):
        stale.unlink()
    compat.set_file_output_path(file_output, render_dir, basename)
    wanted = set(layer_names)
    saved_use = {vl.name: vl.use for vl in sc.view_layers}
    others = [n for n in tree.nodes if n.bl_idname == "CompositorNodeOutputFile" and n != file_output]
    saved_mute = {n.name: n.mute for n in others}
    saved_filter, saved_seed = sc.cycles.filter_width, sc.cycles.seed
    saved_pct = sc.render.resolution_percentage
    saved_adaptive = sc.cycles.use_adaptive_sampling
    try:
        sc.cycles.use_adaptive_sampling = False     # the fringe layers' samples are exact counts
        for vl in sc.view_layers:
            vl.use = vl.name in wanted
        for n in others:
            n.mute = True
        file_output.mute = False
        sc.cycles.filter_width = float(filter_width)
        sc.cycles.seed = int(seed) & 0x7FFFFFFF
        sc.render.resolution_percentage = 100 * int(supersample)
        t0 = time.perf_counter()
        w, h = (int(v * supersample) for v in (sc.render.resolution_x, sc.render.resolution_y))
        with progress.cycles("fringes", f"{what or f'{len(layer_names)} view layers'} at {w} x {h}"):
            bpy.ops.render.render(write_still=False, scene=sc.name)
        return time.perf_counter() - t0
    finally:
        file_output.mute = True
        for n in others:
            n.mute = saved_mute[n.name]
        for vl in sc.view_layers:
            if vl.name in saved_use:
                vl.use = saved_use[vl.name]
        sc.cycles.filter_width, sc.cycles.seed = saved_filter, saved_seed
        sc.render.resolution_percentage = saved_pct
        sc.cycles.use_adaptive_sampling = saved_adaptive


def block_mean(stack: np.ndarray, ss: int) -> np.ndarray:
    """(F, h, w) point samples -> (F, h/ss, w/ss): the ss x ss samples are symmetric about the pixel centre."""
    if ss <= 1:
        return stack
    F, h, w = stack.shape
    return stack.reshape(F, h // ss, ss, w // ss, ss).mean(axis=(2, 4), dtype=np.float32)


def link_ambient_layer(projector, tree, bpy_scene, file_output, node_name: str, samples: int):
    """Build the projector-off layer (Projector.make_ambient_layer) and write its combined pass as
    the grey item AMBIENT_LAYER of `file_output` (a monochrome camera's frame: the compositor's
    grey value, as the fringe layers'); returns its Render Layers node (for teardown)."""
    from . import compat

    vl = projector.make_ambient_layer(samples)
    rl = compat.render_layers_node(tree, bpy_scene, vl.name, name=node_name)
    rl.location = (-1000, 300)
    tree.links.new(compat.rl_socket(rl, "image"), compat.file_output_add_input(file_output, AMBIENT_LAYER, "FLOAT"))
    return rl
