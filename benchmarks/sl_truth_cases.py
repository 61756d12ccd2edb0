"""Real Cycles renders for the structured-light truth benchmark (bench_sl_truth.py), cached as npz.

Two kinds of case, each in both fringe modes ("fast": flat-lit render + synthesis, "render": every
pattern path-traced):

- the shipped demo (`python -m datapipe demo`: the default preset, 4 renders over its scenes): the
  product's Pipeline runs unchanged; `StructuredLightCamera.process` is wrapped so that, per render,
  the fringe radiance it decodes, the native z-buffer depth and instance mask, the pose and `direct`
  (pixels lit directly by the projector: Blender ray cast, tests/sl_scenes.direct_mask) are kept;
- the rig cases of benchmarks/sl_bench_scenes.py (an original-layout pickle preset: camera straight
  down at `height`, rig 'gui' or 'default', a material), rendered with `fringe_mode` pinned.

The cache is keyed by case and mode; a case is rendered only when missing, so re-decoding after a
decoder change costs the decode alone. Fast-mode entries also keep the flat-lit passes
(`direct`/`indirect` radiance at the camera resolution) for the analysis of bounce-lit pixels.
"""
from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

import sl_bench_scenes as S
from sl_scenes import direct_mask

DEMO_RENDERS = 4


def _keep(store: list):
    """Wrap StructuredLightCamera.render_fringes/process so that every render's inputs land in `store`."""
    from datapipe.core import structured_light as SLmod
    from datapipe.io.exr import read_depth, read_mask
    from datapipe.io.layout import RENDER_FILES as FILES

    orig_process = SLmod.StructuredLightCamera.process
    orig_render = SLmod.StructuredLightCamera.render_fringes

    def render_fringes(self, render_dir, seed, T_world_cam=None, rows=None):
        t0 = time.perf_counter()
        flat = getattr(self.strategy, "flat", None)
        if flat is not None:             # fast mode: keep the flat-lit passes too
            orig_flat = flat.render

            def flat_render(*a, **k):
                lit, s = orig_flat(*a, **k)
                ss = int(self.supersample)
                h, w = lit.direct.shape
                self._kept_flat = {f"flat_{n}": getattr(lit, n).reshape(h // ss, ss, w // ss, ss).mean(axis=(1, 3))
                                   for n in ("direct", "indirect")}
                return lit, s
            flat.render = flat_render
        try:
            rad, s = orig_render(self, render_dir, seed, T_world_cam, rows)
        finally:
            if flat is not None:
                del flat.render
        self._kept_rad, self._kept_fringe_s = rad, time.perf_counter() - t0
        return rad, s

    def process(self, rdir, seed, T_world_cam):
        self._kept_flat = {}
        out = orig_process(self, rdir, seed, T_world_cam)
        rdir = Path(rdir)
        depth = read_depth(rdir / FILES["depth"])
        mask = read_mask(rdir / FILES["mask"])
        T = np.asarray(T_world_cam, np.float64)
        store.append({"rad": self._kept_rad, "depth": depth, "mask": mask, "T": T, "K": self.camera.K,
                      "direct": direct_mask(self.scene, self.cfg, T, self.camera.K, depth),
                      "fringe_s": self._kept_fringe_s, **self._kept_flat})
        return out

    SLmod.StructuredLightCamera.render_fringes = render_fringes
    SLmod.StructuredLightCamera.process = process
    return lambda: (setattr(SLmod.StructuredLightCamera, "process", orig_process),
                    setattr(SLmod.StructuredLightCamera, "render_fringes", orig_render))


def demo_key(i: int, mode: str) -> str:
    return f"demo_r{i}_{mode}"


def render_demo(cache: Path, mode: str, log=print) -> None:
    """The demo's renders in fringe mode `mode`, unless cached."""
    from datapipe import config as C
    from datapipe.engine.pipeline import Pipeline

    if all((cache / f"{demo_key(i, mode)}.npz").is_file() for i in range(DEMO_RENDERS)):
        return
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)   # a rig case rendered before leaves its objects behind
    cfg = C.default_config()
    cfg.structured_light.fringe_mode = mode
    store: list = []
    undo = _keep(store)
    try:
        out = Path(tempfile.mkdtemp(prefix="sltruth_demo_"))
        t0 = time.perf_counter()
        for _ in Pipeline(cfg, out / "run").run():
            pass
        log(f"  demo {mode}: {time.perf_counter() - t0:.0f} s")
    finally:
        undo()
    for i, d in enumerate(store):
        np.savez_compressed(cache / f"{demo_key(i, mode)}.npz", **d)


def rig_key(rig: str, height: float, material, mode: str, samples: int | None = None, res=None) -> str:
    """The cache key of a rig case; `samples`: fringe paths per camera pixel other than the default;
    `res`: (W, H) other than 320 x 240."""
    return (f"{S.case_key(rig, height, material)}_{mode}" + (f"_s{int(samples)}" if samples else "")
            + (f"_{int(res[0])}x{int(res[1])}" if res else ""))


def render_rig(cache: Path, cases, mode: str, log=print, samples: int | None = None, res=None) -> None:
    """Rig cases (rig, height, material) in fringe mode `mode`, unless cached (one drop per rig and
    material); `samples`: structured_light.samples instead of the default (the Monte-Carlo noise of
    the render against what a converged render shows), `res`: (W, H) instead of 320 x 240; both
    cached under their own key."""
    import bpy

    from datapipe import config as C
    from datapipe.core.world import BlenderWorld
    from datapipe.draws.seeds import scene_rng

    groups: dict = {}
    for rig, h, mat in cases:
        if not (cache / f"{rig_key(rig, h, mat, mode, samples, res)}.npz").is_file():
            groups.setdefault((rig, mat), []).append(h)
    for (rig, mat), heights in groups.items():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        cfg = S.case_config(rig, heights[0], mat, **({"res": tuple(res)} if res else {}))
        cfg.structured_light.fringe_mode = mode
        if samples:
            cfg.structured_light.samples = int(samples)
        cfg.camera.poses = [C.CameraPose(location=[0.0, 0.0, float(h)]) for h in heights]
        tmp = Path(tempfile.mkdtemp(prefix="sltruth_rig_"))
        store: list = []
        undo = _keep(store)
        try:
            world = BlenderWorld(cfg, tmp / "world")
            world.setup()
            world.start_scene(0, cfg.scene.seed, scene_rng(cfg.scene.seed, 0), 1)
            for k, h in enumerate(heights):
                world.camera.set_pose(k)
                t0 = time.perf_counter()
                world.render(tmp / f"r{k}", k, S.SEED, scene_id=0, render_id=k, base_seed=cfg.scene.seed)
                key = rig_key(rig, h, mat, mode, samples, res)
                log(f"  {key}: {time.perf_counter() - t0:.0f} s")
                np.savez_compressed(cache / f"{key}.npz", **store[-1])
            world.close()
        finally:
            undo()


def load(cache: Path, key: str) -> dict:
    return dict(np.load(cache / f"{key}.npz"))


def write_meta(cache: Path, meta: dict) -> None:
    (cache / "cases.json").write_text(json.dumps(meta, indent=1))
