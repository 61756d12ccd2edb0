"""Issue #29's distractor acceptance on `datapipe/presets/distractors.json` (20 annotated parts, 20
procedural distractors): run it (one scene; `--res`, `--views` keep it short), export BOP, then
count distractors in every ground truth and compare each annotated part's visible fraction with
(a) an independent count (the part's mesh file rasterised alone at its pose against the rendered
depth; hidden where something lies more than 1 mm in front) and (b) the official bop_toolkit's
`calc_gt_info` visibility test (tests/bop_toolkit_check.py; when `bop_toolkit_lib` imports) at its
15 mm and at 1 mm.

    python benchmarks/bench_distractors.py --res 320 240 --views 2
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from harness import ROOT, on_path, parser, preset_dict, run_child

on_path("tests")
import bop_toolkit_check as btc  # noqa: E402
from datapipe.io.bop import export_bop  # noqa: E402
from datapipe.io.exr import read_depth, read_mask  # noqa: E402

OCCLUDER_M = 0.001


def independent_count(out: Path, scene: dict) -> str:
    """Each annotated part's visible pixels counted again from its mesh file and pose against the
    rendered depth, compared with its px_count_visib; and the pixels distractors hide."""
    meshes = {o["obj_id"]: btc.obj_mesh(Path(o["filename"])) for o in scene["objects"]}
    diffs, occluded_by_clutter = [], 0
    for r, rec in enumerate(scene["renders"]):
        rdir = out / "scene.0001" / f"render.{r + 1:04d}"
        depth = read_depth(rdir / "depth.exr").astype(np.float64)
        mask = read_mask(rdir / "mask.exr")
        assert set(np.unique(mask)) <= {0} | {o["mask_index"] for o in rec["objects"]}
        for o in rec["objects"]:
            V, F = meshes[o["obj_id"]]
            full, vis = btc.visible_part(V, F, np.array(rec["K"]), np.array(o["T_cam_obj"]), depth, OCCLUDER_M)
            if not full.any():
                continue
            occluded_by_clutter += int((full & ~vis & (mask == 0)).sum())
            diffs.append(abs(o["px_count_visib"] - int(vis.sum())))
    return (f"independent count: {len(diffs)} instances, visible px differing by max {max(diffs)} / mean "
            f"{np.mean(diffs):.2f} px; {occluded_by_clutter} px of annotated parts hidden by distractors")


def ground_truth_counts(out: Path, bop: Path, scene: dict) -> str:
    """Parts, distractors and annotations in scene.json and every BOP ground truth file."""
    sim = scene["simulation"]
    names = [o["name"] for o in scene["objects"]]
    chunk = bop / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    info = json.loads((chunk / "scene_gt_info.json").read_text())
    coco = json.loads((chunk / "scene_gt_coco.json").read_text())
    clutter = [n for n in names if n.startswith("clutter_")]
    return (f"{sim['parts']} parts in the bin ({sim.get('distractors')} distractors), {len(sim['removed'])} lost, "
            f"{len(sim['interpenetrating_pairs'])} interpenetrating pairs; scene.json objects {len(names)} "
            f"(distractors among them: {len(clutter)}); scene_gt {sum(len(v) for v in gt.values())}, scene_gt_info "
            f"{sum(len(v) for v in info.values())}, COCO {len(coco['annotations'])} annotations, obj_ids "
            f"{sorted({g['obj_id'] for v in gt.values() for g in v})}; models "
            f"{sorted(p.name for p in (bop / 'models').glob('*.ply'))}")


def run_preset(a, out: Path) -> None:
    """distractors.json at --res with --views renders of one scene, through the CLI."""
    preset = ROOT / "datapipe" / "presets" / "distractors.json"
    d = preset_dict(preset)
    d["camera"]["resolution"] = a.res
    d["scene"].update(num_renders=a.views, min_renders_per_scene=a.views, max_renders_per_scene=a.views,
                      seed=a.seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    (out.parent / "preset.json").write_text(json.dumps(d))
    child = run_child([sys.executable, "-m", "datapipe", "run", str(out.parent / "preset.json"), "--out", str(out),
                       "--force", "--quiet"], env=dict(os.environ, PYTHONPATH=str(ROOT)))
    if child.returncode:
        raise RuntimeError(f"datapipe run of distractors.json failed (exit {child.returncode})")


def main(argv=None) -> int:
    ap = parser(__doc__, quick="--views 1")
    ap.add_argument("--res", type=int, nargs=2, default=[320, 240])
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.quick:
        a.views = 1
    with tempfile.TemporaryDirectory() as tmp:
        out = a.out or Path(tmp) / "run"
        run_preset(a, out)
        bop = out.parent / "bop"
        export_bop(out, bop)
        scene = json.loads((out / "scene.0001" / "scene.json").read_text())
        print(ground_truth_counts(out, bop, scene))
        print(independent_count(out, scene))
        if btc.toolkit() is None:
            print("bop_toolkit: not importable, its check was not run")
            return 0
        for delta in (btc.DELTA_MM, 1.0):
            s = btc.check(bop, delta_mm=delta)
            print(f"bop_toolkit at {delta:g} mm: {s['gt_info_equal']}/{s['instances']} scene_gt_info entries "
                  f"equal, {s['visib_px_differing']} of {s['visib_px']} visible px differ "
                  f"({s['toolkit_only_px']} visible to the toolkit only)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
