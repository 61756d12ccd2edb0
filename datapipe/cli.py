"""Headless entry points: `python -m datapipe run|demo|validate|show|bop`.

Works on the `bpy` wheel and inside Blender:
    blender -b scene.blend --python-expr "import datapipe.cli as c; c.main(['run', 'preset.json', '--out', 'out'])"
User mistakes print one clear message and exit 2; nothing is written before the input is checked.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import config as config_mod
from .errors import ConfigError, DataPipeError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m datapipe", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    def run_args(sp, preset: bool):
        if preset:
            sp.add_argument("preset", help="JSON preset or an original DataPipe inputs pickle")
        sp.add_argument("--out", help="output folder (default: the preset's output.path)")
        sp.add_argument("--seed", type=int, help="base seed (default: the preset's scene.seed)")
        sp.add_argument("--resume", action="store_true", help="continue a killed run in --out")
        sp.add_argument("--force", action="store_true", help="empty --out first if it holds an earlier DataPipe run")
        sp.add_argument("--shard", default="0/1", help="i/n: make only the i-th of n scene ranges (0-based)")
        sp.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help="fan the run out over Ray (no address: a local Ray instance)")
        sp.add_argument("--shards", type=int, default=None, help="with --ray: number of shards")
        sp.add_argument("--retries", type=int, default=2, help="with --ray: retries of a failed shard")
        sp.add_argument("--quiet", action="store_true", help="no per-render progress lines")

    run_args(sub.add_parser("run", help="make a dataset from a preset"), preset=True)
    demo = sub.add_parser("demo", help="make the embedded demo dataset (a bin with a few small parts)")
    run_args(demo, preset=False)
    demo.add_argument("--structured-light", choices=("on", "off"), default=None,
                      help="override the demo's structured-light switch")
    v = sub.add_parser("validate", help="check a preset and list every problem")
    v.add_argument("preset")
    s = sub.add_parser("show", help="contact sheets for a run folder")
    s.add_argument("run_dir")
    s.add_argument("--out", help="sheet folder (default: RUN_DIR/sheets)")
    s.add_argument("--max", type=int, default=None, help="at most this many per-render sheets")
    s.add_argument("--no-overview", action="store_true", help="skip overview.png")
    s.add_argument("--grid", type=int, default=None, metavar="N",
                   help="instead of per-render sheets: one grid.png of N random renders")
    s.add_argument("--grid-seed", type=int, default=0, help="which renders --grid draws (default 0)")
    b = sub.add_parser("bop", help="export a finished native run as a BOP dataset")
    b.add_argument("run_dir")
    b.add_argument("--out", help="BOP folder (default: RUN_DIR/bop)")
    b.add_argument("--depth-scale", type=float, default=0.1, help="mm per depth PNG unit (default 0.1)")
    b.add_argument("--chunk-size", type=int, default=1000, help="images per BOP scene folder (default 1000)")
    return p


def _err(msg: str) -> int:
    print(f"datapipe: error: {msg}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "validate":
            cfg = config_mod.load(args.preset)
            cfg.validate()
            from .part_fit import part_fit_warnings
            for w in part_fit_warnings(cfg):
                print(f"datapipe: warning: {w}", file=sys.stderr)
            print(f"{args.preset}: OK ({cfg.scene.num_renders} renders, {len(cfg.objects)} object entries, "
                  f"{len(cfg.camera.poses)} camera poses, structured light "
                  f"{'on' if cfg.structured_light.enabled else 'off'})")
            return 0
        if args.command == "show":
            from . import show
            argv2 = [args.run_dir] + (["--out", args.out] if args.out else []) \
                + (["--max", str(args.max)] if args.max is not None else []) \
                + (["--no-overview"] if args.no_overview else []) \
                + (["--grid", str(args.grid), "--grid-seed", str(args.grid_seed)] if args.grid is not None else [])
            return show.main(argv2)
        if args.command == "bop":
            from .io.bop import export_bop
            from .io.layout import BOP_DIR
            out = Path(args.out) if args.out else Path(args.run_dir) / BOP_DIR
            export_bop(Path(args.run_dir), out, depth_scale=args.depth_scale, chunk_size=args.chunk_size)
            print(f"BOP dataset written to {out}")
            return 0
        if args.command == "demo":
            cfg = config_mod.default_config()
            if args.structured_light is not None:
                cfg.structured_light.enabled = args.structured_light == "on"
            return _run(cfg, args, preset_path=None)
        cfg = config_mod.load(args.preset)
        return _run(cfg, args, preset_path=args.preset)
    except (ConfigError, DataPipeError) as e:
        return _err(str(e))


def _run(cfg, args, preset_path) -> int:
    from .seeds import parse_shard
    try:
        shard = parse_shard(args.shard)
    except ValueError as e:
        return _err(str(e))
    if args.ray is not None:
        from .distributed import run_distributed
        if preset_path is None:
            raise DataPipeError("--ray needs a preset file (fix: `python -m datapipe run "
                                f"{config_mod.presets_dir() / 'default.json'} --ray` runs the demo preset)")
        run_distributed(preset_path, args.out or cfg.output.path,
                        address=None if args.ray == "local" else args.ray,
                        num_shards=args.shards, seed=args.seed, retries=args.retries,
                        extra_args=["--quiet"] if args.quiet else [])
        return 0
    from .core.pipeline import Pipeline
    pipe = Pipeline(cfg, args.out, resume=args.resume, force=args.force, shard=shard, seed=args.seed)
    pipe.check()            # every input problem before any Blender work
    _prepare_blender()
    t0 = time.perf_counter()
    last = None
    for last in pipe.run():
        if not args.quiet or last.stage in ("done", "cancelled"):
            print(last.line(), file=sys.stderr, flush=True)
    if last is not None and last.stage == "done":
        from .show import overview_after_run
        overview_after_run(pipe.out, pipe.cfg.output)
    print(f"dataset: {pipe.out} ({pipe.total} renders, {time.perf_counter() - t0:.1f} s)")
    return 0


def _prepare_blender() -> None:
    """On the bpy module start from an empty scene; inside Blender with a .blend open, keep it."""
    import bpy
    if not bpy.data.filepath:
        bpy.ops.wm.read_factory_settings(use_empty=True)


if __name__ == "__main__":
    sys.exit(main())
