"""Headless entry points: `python -m datapipe run|demo|validate|show|bop|sensors`.

Works on the `bpy` wheel and inside Blender:
    blender -b scene.blend --python-expr "import datapipe.cli as c; c.main(['run', 'preset.json', '--out', 'out'])"
Exit status: 0 done; 2 a mistake in the input or arguments (one message: field path + fix, nothing
written); 1 the file system or an output folder's state stopped the run (path + fix; `--debug` shows
the traceback); 130 stopped by Ctrl-C/SIGTERM (`--resume` continues).
"""
from __future__ import annotations

import argparse
import errno
import os
import sys
import time
import traceback
from pathlib import Path

from . import config as config_mod
from .engine.blender_log import BlenderLog
from .errors import ConfigError, DataPipeError
from .io.layout import BLENDER_LOG
from .io.outdir import OutputStateError
from .engine.session import blender_session, check_config, check_run_input, print_warnings, run_pipeline


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m datapipe", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    def run_args(sp, preset: bool):
        if preset:
            sp.add_argument("preset", help="JSON preset or an original DataPipe inputs pickle")
        sp.add_argument("--out", help="output folder (default: the preset's output.path)")
        sp.add_argument("--seed", type=int, help="base seed (default: the preset's scene.seed)")
        sp.add_argument("--resume", action="store_true", help="continue a killed run in --out")
        sp.add_argument("--force", action="store_true", help="first remove the files an earlier run in --out "
                        "wrote (as its manifest.json lists them; nothing else), after every check passed")
        sp.add_argument("--shard", default="0/1", help="i/n: make only the i-th of n scene ranges (0-based)")
        sp.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help="fan the run out over Ray (no address: a local Ray instance)")
        sp.add_argument("--shards", type=int, default=None, help="with --ray: number of shards")
        sp.add_argument("--retries", type=int, default=2, help="with --ray: retries of a failed shard")
        sp.add_argument("--quiet", action="store_true", help="no per-render progress lines")
        sp.add_argument("--verbose", action="store_true", help="show Blender's own output on the terminal too "
                        f"(it always goes to OUT/{BLENDER_LOG})")
        sp.add_argument("--debug", action="store_true", help="show the traceback of a file-system error")
        sp.add_argument("--strict", action="store_true", help="stop at a render that fails a quality gate "
                        "(black or saturated RGB, no visible part, < 1%% structured-light depth, parts lost)")

    run_args(sub.add_parser("run", help="make a dataset from a preset"), preset=True)
    demo = sub.add_parser("demo", help="make the embedded demo dataset (a bin with a few small parts)")
    run_args(demo, preset=False)
    demo.add_argument("--structured-light", choices=("on", "off"), default=None,
                      help="override the demo's structured-light switch")
    v = sub.add_parser("validate", help="check a preset (mesh files imported too) and list every problem")
    v.add_argument("preset")
    v.add_argument("--verbose", action="store_true", help="show Blender's own output (mesh imports)")
    v.add_argument("--debug", action="store_true", help="show the traceback of a file-system error")
    s = sub.add_parser("show", help="contact sheets for a run folder")
    s.add_argument("run_dir")
    s.add_argument("--out", help="sheet folder (default: RUN_DIR/sheets)")
    s.add_argument("--max", type=int, default=None, help="at most this many per-render sheets")
    s.add_argument("--no-overview", action="store_true", help="skip overview.png")
    s.add_argument("--grid", type=int, default=None, metavar="N",
                   help="instead of per-render sheets: one grid.png of N random renders")
    s.add_argument("--grid-seed", type=int, default=0, help="which renders --grid draws (default 0)")
    sub.add_parser("sensors", help="list the real-device presets (\"device\": NAME in a preset) with their "
                   "resolution, field of view, working distance, precision and source")
    b = sub.add_parser("bop", help="export a finished native run as a BOP dataset")
    b.add_argument("run_dir")
    b.add_argument("--out", help="BOP folder (default: RUN_DIR/bop)")
    b.add_argument("--depth-scale", type=float, default=0.1, help="mm per depth PNG unit (default 0.1)")
    b.add_argument("--chunk-size", type=int, default=1000, help="images per BOP scene folder (default 1000)")
    b.add_argument("--split", default="train_pbr", help="split folder name (default train_pbr, as the official "
                   "physically based training splits)")
    b.add_argument("--rgb-format", choices=("jpg", "png"), default="jpg", help="RGB files (default jpg, as "
                   "the official train_pbr splits)")
    b.add_argument("--jpg-quality", type=int, default=95, help="JPEG quality 1..100 (default 95)")
    b.add_argument("--sensor", default=None, help="BOP-Industrial name of the scanner's folders (gray_NAME/, "
                   "depth_NAME/ ...; default: the run's output.bop_sensor, else its device's maker, else 'sl')")
    b.add_argument("--xyz-crop", action="store_true",
                   help="also write GDRNPP's amodal xyz_crop/ targets per instance (docs/DATASETS.md)")
    b.add_argument("--amodal-coco", action="store_true",
                   help="also write scene_gt_coco_amodal.json (full silhouettes, UOAIS' fields) per chunk")
    return p


def _printable(path) -> str:
    """A path for stdout: a file name's non-UTF-8 bytes (surrogate escapes in Python) as \\x.. escapes,
    so a strict UTF-8 terminal prints it instead of raising UnicodeEncodeError."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _err(msg: str, code: int = 2) -> int:
    print(f"datapipe: error: {msg}", file=sys.stderr)
    return code


_OS_FIXES = {
    errno.EACCES: "check the folder's permissions or choose another --out",
    errno.EPERM: "check the folder's permissions or choose another --out",
    errno.EROFS: "the file system is read-only: choose another --out",
    errno.ENOSPC: "free disk space (or choose another --out), then run again with --resume",
    errno.EDQUOT: "free disk space (or choose another --out), then run again with --resume",
    errno.ENOENT: "check that the folder exists and was not removed during the run",
    errno.ENOTDIR: "a part of the path is a file, not a folder: check the path",
    errno.EISDIR: "the path is a folder where a file was expected: check the path",
}


def _os_error(e: OSError) -> int:
    where = e.filename or "?"
    fix = _OS_FIXES.get(e.errno, "check the path and the disk, then run again (with --resume for a run)")
    return _err(f"{where}: {e.strerror or e} (fix: {fix})", 1)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    debug = getattr(args, "debug", False)
    try:
        return _command(args)
    except OutputStateError as e:
        return _err(str(e), 1)
    except (ConfigError, DataPipeError) as e:
        return _err(str(e))
    except OSError as e:
        if debug:
            traceback.print_exc()
        return _os_error(e)
    except KeyboardInterrupt:
        print("datapipe: interrupted (nothing half-written is kept as complete; --resume continues a run)",
              file=sys.stderr)
        return 130
    except MemoryError:
        if debug:
            traceback.print_exc()
        return _err("out of memory (fix: lower the resolution, samples or structured_light.steps)", 1)


def _command(args) -> int:
    if args.command == "validate":
        from .engine.gate import memory_summary
        from .config.plan import FringePlan
        cfg = config_mod.load(args.preset)
        report = check_config(cfg, verbose=args.verbose)
        print_warnings(report.warnings)
        cams = (f"{len(cfg.camera.poses)} camera poses" if cfg.camera.sampler.kind == "pool"
                else f"camera poses drawn by the {cfg.camera.sampler.kind} sampler")
        sl = cfg.structured_light
        sl_text = (f"on ({'; '.join(FringePlan.from_config(report.cfg).describe() + [memory_summary(report.cfg)])})"
                   if sl.enabled else "off")
        print(f"{_printable(args.preset)}: OK ({cfg.scene.num_renders} renders, {len(cfg.objects)} object entries, "
              f"{cams}, structured light {sl_text})")
        return 0
    if args.command == "sensors":
        from .checks.device_checks import table
        print(table())
        return 0
    if args.command == "show":
        from . import show
        from .io.layout import SHEETS_DIR
        _refuse_links_in_run_dir(args, SHEETS_DIR)
        return show.run_command(args)
    if args.command == "bop":
        from .io.bop import export_bop
        from .io.layout import BOP_DIR
        _refuse_links_in_run_dir(args, BOP_DIR)
        out = Path(args.out) if args.out else Path(args.run_dir) / BOP_DIR
        export_bop(Path(args.run_dir), out, depth_scale=args.depth_scale, chunk_size=args.chunk_size,
                   split=args.split, rgb_format=args.rgb_format, jpg_quality=args.jpg_quality, sensor=args.sensor,
                   xyz_crop=args.xyz_crop, amodal_coco=args.amodal_coco)
        print(f"BOP dataset written to {out}")
        return 0
    if args.command == "demo":
        cfg = config_mod.default_config()
        if args.structured_light is not None:
            cfg.structured_light.enabled = args.structured_light == "on"
        return _run(cfg, args, preset_path=None)
    cfg = config_mod.load(args.preset)
    return _run(cfg, args, preset_path=args.preset)


def _refuse_links_in_run_dir(args, folder: str) -> None:
    """`show`/`bop` writing into the run folder (no --out): not through a link there."""
    if args.out is None:
        from .io.outdir import refuse_links_under
        refuse_links_under(Path(args.run_dir), folder)


def _run(cfg, args, preset_path) -> int:
    from .draws.seeds import parse_shard
    try:
        shard = parse_shard(args.shard)
    except ValueError as e:
        return _err(str(e))
    check_run_input(cfg, args.out, args.seed)
    if args.ray is not None:
        from .engine.distributed import run_distributed
        if preset_path is None:
            raise DataPipeError("--ray needs a preset file (fix: `python -m datapipe run "
                                f"{config_mod.presets_dir() / 'default.json'} --ray` runs the demo preset)")
        run_distributed(preset_path, args.out or cfg.output.path,
                        address=None if args.ray == "local" else args.ray,
                        num_shards=args.shards, seed=args.seed, retries=args.retries,
                        extra_args=(["--quiet"] if args.quiet else []) + (["--strict"] if args.strict else [])
                        + (["--verbose"] if args.verbose else []),
                        blender_session=lambda: blender_session(BlenderLog(verbose=args.verbose)),
                        warn=print_warnings)     # the driver's gate, before OUT/_shards/ is written
        return 0
    t0 = time.perf_counter()

    def print_event(p) -> None:
        if not args.quiet or p.stage in ("done", "cancelled", "force"):     # force: what --force kept
            print(p.line(), file=sys.stderr, flush=True)
    pipe, last = run_pipeline(cfg, args.out, resume=args.resume, force=args.force, shard=shard, seed=args.seed,
                              strict=args.strict, verbose=args.verbose, on_event=print_event,
                              on_step=None if args.quiet else _print_step)
    if last is not None and last.stage == "cancelled":
        return 130
    print(f"dataset: {_printable(pipe.out)} ({pipe.total} renders, {time.perf_counter() - t0:.1f} s)")
    return 0


def _print_step(p) -> None:
    """A line inside a scene (datapipe/engine/progress.py); may come from the heartbeat thread."""
    print(p.line(), file=sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
