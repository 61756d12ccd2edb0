"""BOP export cost per image: 50 box instances at 640x480 (synthetic native run, no Blender).

    .venv/bin/python benchmarks/bench_bop.py [--instances 50] [--renders 4] [--subdiv 4] [--repeat 3]
                                             [--render-seconds S]

Makes one synthetic native scene (tests/fixtures_native.py: exact ray-cast depth/mask of boxes on a
floor, structured-light-like depth) and times BopWriter.add_scene on it, per image, with a breakdown:
full-silhouette rasterisation, PNG writes (rgb copy, depth, depth_sl, masks), JSON. Compares with a
reference render time per image (--render-seconds, or the 'render' stage of a run.json given with
--run-json). Writes benchmarks/results/bop_<instances>inst_<W>x<H>.md.

When `bop_toolkit_lib` can be imported (a bop_toolkit checkout and its imageio / pypng on
PYTHONPATH), the export is also judged by the toolkit (tests/bop_toolkit_check.py): its loaders,
`misc.project_pts` of the models_eval points, its visibility test on the exported depth, and the
report says what agrees.
"""
from __future__ import annotations

import json
import platform
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

from harness import RESULTS, Stopwatch, machine, on_path, parser

on_path("tests")
import fixtures_native as fx  # noqa: E402
import bop_toolkit_check  # noqa: E402
from datapipe.io import bop  # noqa: E402
from datapipe.io.models import load_models  # noqa: E402
from datapipe.io.silhouette import rasterize_silhouette  # noqa: E402


def make_parser():
    ap = parser(__doc__, quick="10 instances, 1 render, 1 repeat (seconds)")
    ap.add_argument("--instances", type=int, default=50)
    ap.add_argument("--renders", type=int, default=4)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--subdiv", type=int, default=4, help="grid per box face (faces per box = 12 * subdiv^2)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--render-seconds", type=float, default=None, help="reference render time per image")
    ap.add_argument("--run-json", default=None, help="take the reference from a real run's run.json stats")
    ap.add_argument("--no-sl", action="store_true")
    return ap


def measure(a, tmp: Path) -> dict:
    """Make the synthetic scene, then per repeat: BopWriter's set-up, add_scene per image and the
    rasterisation share alone (seconds); the last repeat's export is kept for the toolkit's judgement."""
    cfg = fx.default_config(num_renders=a.renders, min_per_scene=a.renders, max_per_scene=a.renders,
                            resolution=(a.width, a.height), structured_light=not a.no_sl)
    with Stopwatch() as t_fixture:
        run = fx.make_native_run(tmp / "native", cfg=cfg, min_boxes=a.instances, max_boxes=a.instances,
                                 spread=0.16, mesh_subdiv=a.subdiv)
    scene_dir = run / "scene.0001"
    scene = json.loads((scene_dir / "scene.json").read_text())
    n_img = len(scene["renders"])
    models = load_models(run / "models")
    totals, rasters, setups = [], [], []
    for k in range(a.repeat):
        root = tmp / f"bop{k}"
        with Stopwatch() as t:
            w = bop.BopWriter(root, models_dir=run / "models")     # once per dataset: models, models_eval
        setups.append(t.wall_s)
        with Stopwatch() as t:
            w.add_scene(scene_dir)
        totals.append(t.wall_s / n_img)
        with Stopwatch() as t:                                      # the rasterisation share, alone
            for rd in scene["renders"]:
                K = np.asarray(rd["K"])
                for o in rd["objects"]:
                    T = np.asarray(o["T_cam_obj"])
                    m = models[o["obj_id"]]
                    rasterize_silhouette(m.verts_mm, m.faces, K, T[:3, :3], T[:3, 3] * 1000, a.width, a.height)
        rasters.append(t.wall_s / n_img)
        if k < a.repeat - 1:
            shutil.rmtree(root)
    judged = bop_toolkit_check.check(root) if bop_toolkit_check.toolkit() is not None else None
    return dict(n_img=n_img, n_inst=[len(r["objects"]) for r in scene["renders"]], t_fixture=t_fixture.wall_s,
                totals=totals, per_img=statistics.median(totals), raster=statistics.median(rasters),
                setup=statistics.median(setups), judged=judged)


def reference(a) -> tuple[float | None, str | None]:
    """The render time per image to compare with: --render-seconds, or a run.json's render stage."""
    if a.render_seconds is not None or not a.run_json:
        return a.render_seconds, "--render-seconds" if a.render_seconds is not None else None
    rj = json.loads(Path(a.run_json).read_text())
    ref = rj["stats"]["seconds"]["render"] / max(1, sum(rj["plan"][i] for i in range(len(rj["plan"]))
                                                        if f"scene.{i + 1:04d}" in rj.get("scenes_done", [])))
    cam, rnd = rj["config"]["camera"], rj["config"]["render"]
    return ref, (f"{a.run_json}: {cam['resolution'][0]}x{cam['resolution'][1]}, {rnd['samples']} samples, "
                 f"structured light {'on' if rj['config']['structured_light']['enabled'] else 'off'}")


def judged_line(j: dict | None) -> str:
    if not j:
        return "- bop_toolkit: not importable, its checks were not run"
    return (f"- judged by bop_toolkit ({j['images']} images, {j['instances']} instances): visible masks "
            f"recomputed with its visibility test (15 mm, bop19) identical for {j['masks_visib_equal']}/"
            f"{j['instances']} ({j['visib_px_differing']} of {j['visib_px']} pixels differ, "
            f"{j['toolkit_only_px']} of them only its: occluded within 15 mm of the occluder); px_count_visib and "
            f"bbox_visib equal for {j['gt_info_equal']}/{j['instances']}; bbox_obj within 1.5 px of its projected "
            f"models_eval points for {j['bbox_obj_within_1_5px']}/{j['instances']}; projected points on `mask` "
            f"(1 px slack) {j['points_on_mask'] / max(1, j['points']) * 100:.2f}%; diameters within "
            f"{j['diameter_max_err_mm']:.1e} mm")


def report_lines(a, m: dict) -> list[str]:
    ref, ref_src = reference(a)
    per_img, raster, n_inst = m["per_img"], m["raster"], m["n_inst"]
    return [
        f"# BOP export cost: {a.instances} instances at {a.width}x{a.height}",
        "",
        f"- machine: {machine()} (shared), Python {platform.python_version()}",
        f"- data: synthetic native scene ({m['n_img']} renders, {min(n_inst)}-{max(n_inst)} annotated instances each, "
        f"box models with {12 * a.subdiv ** 2} triangles, structured light {'off' if a.no_sl else 'on'}); fixture "
        f"made in {m['t_fixture']:.1f} s",
        f"- once per dataset (models/ copied, models_eval/ resampled): {m['setup']:.2f} s",
        f"- BopWriter.add_scene: **{per_img:.3f} s per image** (median of {a.repeat}; runs "
        f"{', '.join(f'{t:.3f}' for t in m['totals'])} s)",
        f"  - full-silhouette rasterisation: {raster:.3f} s per image ({raster / per_img * 100:.0f}%)",
        f"  - the rest (rgb JPEG, depth/depth_sl/mask/mask_visib PNG writes, EXR reads, JSON): "
        f"{per_img - raster:.3f} s per image",
        f"- reference render time: {ref:.2f} s per image ({ref_src}); BOP export adds {per_img / ref * 100:.1f}% to it"
        if ref else "- reference render time: not given (pass --render-seconds or --run-json)",
        judged_line(m["judged"]),
    ]


def main(argv=None) -> int:
    a = make_parser().parse_args(argv)
    if a.quick:
        a.instances, a.renders, a.repeat = 10, 1, 1
    tmp = Path(tempfile.mkdtemp(prefix="bench_bop_"))
    try:
        text = "\n".join(report_lines(a, measure(a, tmp))) + "\n"
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(text)
    out = RESULTS / f"bop_{a.instances}inst_{a.width}x{a.height}.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"written {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
