"""Generation across many processes or machines on Ray (optional extra: `pip install datapipe[ray]`).

    python -m datapipe run PRESET --out DIR --ray [ADDRESS] [--shards N]

The run's scenes are split into N contiguous shards (datapipe.draws.seeds.shard_scenes). Each shard is one
Ray task that launches the headless runner in its own process (bpy is one per process):

    <python> -m datapipe run SHARD_PRESET --out DIR/_shards/shard_I_of_N --shard I/N --seed S --resume

A failed shard (non-zero exit, killed process, lost worker) is retried up to `retries` times; with
--resume the retry continues where the shard stopped, making only the scenes that are not complete.
When every shard is done the shard folders are merged into DIR: the scene folders' files are moved
(their names and image ids are global already), models/ is copied, the preset's writers run on the
merged scenes (datapipe.io.writers: output_dict.pickle rebuilt from the scenes' scene.json, BOP when
the preset asks for it), run.json says the whole run is complete; then the overview sheet is drawn
if the preset asks for it. Every write into DIR goes through its opened handle, never a link
(datapipe/io/guard.py), and the merge records DIR's manifest as a one-process run does, so --force
and --resume treat the merged run alike (docs/OUTPUT_SAFETY.md). Re-running the same command after
a failure resumes: finished shards are kept. A pick sequence (scene.picks) stays in one shard.

Shards run with output.formats = ["native"] (BOP is exported once, after the merge) and no overview.
On a cluster DIR must be on a filesystem every node mounts at the same path, and datapipe (with bpy)
must be installed in the Python that Ray workers run.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, ContextManager, Iterable, Sequence

from .. import config as config_mod
from ..io import guard, layout, outdir
from ..io.bop_sensor import sensor_for_config
from . import gate
from ..errors import DataPipeError
from ..io.files import copy_atomic, make_dirs, open_append, read_json, write_json_atomic, write_text_atomic
from ..io.manifest import Manifest
from ..io.layout import config_identity, scene_name
from ..io.writers import open_writers
from ..draws.picks import sequence_length
from ..draws.seeds import plan_scenes, shard_scenes
from . import stats

SHARDS_DIR = "_shards"
SHARD_PRESET = "preset.json"
ATTEMPTS_FILE = ".datapipe_attempts"


def shard_dir_name(i: int, n: int) -> str:
    return f"shard_{i:04d}_of_{n:04d}"


def _load_prctl():                               # one shard, inside a Ray worker: its runner process
    try:
        import ctypes
        return ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except Exception:
        return None


_PRCTL = _load_prctl() if sys.platform.startswith("linux") else None


def _die_with_parent():            # in the child before exec: die when the Ray worker running us dies
    if _PRCTL is not None:
        _PRCTL(1, 9)               # PR_SET_PDEATHSIG, SIGKILL (resolved before the fork)


def _stop_previous_runner(pid_file: Path, shard_dir: Path) -> None:
    """A retry on the same host first ends a runner an earlier attempt left behind (its worker was
    killed before it could): only a live process whose command line names this shard's folder."""
    try:
        host, pid = pid_file.read_text().split()
        pid = int(pid)
    except (OSError, ValueError):
        return
    if host != socket.gethostname() or pid <= 0:
        return
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return                                   # gone (or no /proc): nothing to stop
    if str(shard_dir).encode() not in cmdline:
        return                                   # the pid now belongs to another process
    try:
        os.kill(pid, signal.SIGKILL)
        for _ in range(50):                      # until it is gone (or a zombie)
            stat = Path(f"/proc/{pid}/stat").read_text()
            if stat.rsplit(")", 1)[1].split()[0] == "Z":
                break
            time.sleep(0.1)
    except (ProcessLookupError, PermissionError, OSError, IndexError):
        pass


def run_shard(spec: dict) -> dict:
    """Run one shard to completion in a child process; raise on failure (Ray retries the task).

    spec: preset, shard_dir, shard (i, n), seed, scenes (names it must make), extra_args, runner,
    env (extra environment variables)."""
    shard_dir = Path(spec["shard_dir"])
    # the shard's folder, attempts, pid and log files: written through the handle of the run's output
    # folder (OUT/_shards/... never through a link); not recorded, the merge drops them (the logs are
    # recorded as it moves them into OUT/logs)
    with guard.guarding(Path(spec.get("out") or shard_dir.parent.parent)):
        return _run_shard(spec, shard_dir)


def _run_shard(spec: dict, shard_dir: Path) -> dict:
    i, n = spec["shard"]
    make_dirs(shard_dir)
    attempts_file = shard_dir.parent / f"{shard_dir.name}{ATTEMPTS_FILE}"
    attempt = (int(attempts_file.read_text()) if attempts_file.is_file() else 0) + 1
    write_text_atomic(attempts_file, str(attempt))
    runner = list(spec.get("runner") or [sys.executable, "-m", "datapipe", "run"])
    cmd = runner + [spec["preset"], "--out", str(shard_dir), "--shard", f"{i}/{n}", "--seed", str(spec["seed"]),
                    "--resume", *spec.get("extra_args", ())]
    log_path = shard_dir.parent / f"{shard_dir.name}.log"
    env = dict(os.environ)
    env.update({str(k): str(v) for k, v in (spec.get("env") or {}).items()})
    t0 = time.time()
    with open_append(log_path) as log:
        log.write(f"\n=== attempt {attempt} on {socket.gethostname()}: {' '.join(cmd)}\n".encode())
        log.flush()
        pid_file = shard_dir.parent / f"{shard_dir.name}.pid"
        _stop_previous_runner(pid_file, shard_dir)
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=str(shard_dir.parent), env=env,
                                preexec_fn=_die_with_parent if _PRCTL is not None else None)
        write_text_atomic(pid_file, f"{socket.gethostname()} {proc.pid}\n")
        try:
            while proc.poll() is None:
                time.sleep(0.05)
        except BaseException:        # the task was cancelled: take the runner down with it
            proc.kill()
            proc.wait()
            raise
        finally:
            if proc.poll() is not None:
                _remove_file(pid_file)
    rc = proc.returncode
    missing = [s for s in spec["scenes"] if not layout.scene_complete(shard_dir / s)]
    if rc != 0 or missing:
        tail = log_path.read_text()[-1500:] if log_path.is_file() else ""
        raise RuntimeError(f"shard {i}/{n} failed on attempt {attempt} (exit code {rc}"
                           f"; {len(missing)} scene(s) not complete); "
                           f"log: {log_path}\n{tail}")
    return {"shard": [i, n], "dir": str(shard_dir), "host": socket.gethostname(), "attempts": attempt,
            "seconds": round(time.time() - t0, 3), "scenes": list(spec["scenes"])}


def _remove_file(path: Path) -> None:
    """Unlink `path`; inside a guarded output folder from its folder's handle (no link on the way)."""
    g = guard.active_for(path)
    if g is None:
        path.unlink(missing_ok=True)
        return
    d = g.open_dir(g.rel(path.parent) or "", create=False)
    try:
        os.unlink(path.name, dir_fd=d)
    except FileNotFoundError:
        pass
    finally:
        os.close(d)


# ------------------------------------------------------------------------------------------------
# merging

def merge_shards(shard_dirs: Sequence[str | os.PathLike], out_dir: str | os.PathLike, *, move: bool = True,
                 config: dict | None = None, shard_reports: Iterable[dict] = (),
                 manifest: Manifest | None = None) -> dict:
    """Merge shard output folders into one native run folder `out_dir`.

    Checks everything before touching anything: each shard is a DataPipe run of the same plan, seed
    and preset; every scene of the plan is complete in exactly one shard (duplicates and missing
    scenes are refused, naming them and the shard to re-run); image ids are the global ones. Then
    moves (or copies, move=False) the scene folders, copies models/, runs the preset's writers on
    the merged scenes (output_dict.pickle rebuilt from the scenes' scene.json; BOP when the preset
    asks for it) and writes run.json for the whole run. `config`: the preset dict to record in
    run.json (default: the shards' own).

    Every write into `out_dir` goes through its opened handle (datapipe/io/guard.py: a link put at a
    scene or render folder or a temporary file at any moment is refused, naming it) and is recorded
    in its manifest as a one-process run records it, so --force and --resume treat the merged run
    alike. `manifest`: the run's (the Ray driver's, which holds the folder's lock); default: the
    folder's own, under its lock for the merge."""
    shard_dirs = [Path(d) for d in shard_dirs]
    out = Path(out_dir)
    runs = _shard_runs(shard_dirs)
    ref = runs[0]
    plan = [int(x) for x in ref["plan"]]
    expected = [scene_name(i) for i in range(len(plan))]
    owner, problems = _scene_owners(shard_dirs, runs, out, plan)
    scene_docs = {s: read_json(d / s / layout.SCENE_FILE) for s, d in owner.items()}
    problems += _image_id_problems(owner, scene_docs, plan)
    model_src = _model_source(shard_dirs, problems)
    if problems:
        raise DataPipeError("merge refused, nothing was moved:\n  - " + "\n  - ".join(problems))

    out.mkdir(parents=True, exist_ok=True)
    if manifest is not None:
        return _merge(manifest, shard_dirs, out, runs, owner, scene_docs, model_src, move, config, shard_reports)
    with outdir.OutLock(out):
        m = Manifest.load(out) or Manifest(out)
        try:
            return _merge(m, shard_dirs, out, runs, owner, scene_docs, model_src, move, config, shard_reports)
        finally:
            m.close()


def _merge(m: Manifest, shard_dirs, out: Path, runs, owner, scene_docs, model_src, move, config, shard_reports):
    """merge_shards' writes, once everything is checked: through OUT's handle, recorded in `m`."""
    with m.writing() as g:
        summary = _merge_writes(g, shard_dirs, out, runs, owner, scene_docs, model_src, move, config, shard_reports)
        m.update()
    return summary


def _merge_writes(g, shard_dirs, out: Path, runs, owner, scene_docs, model_src, move, config, shard_reports):
    ref = runs[0]
    plan = [int(x) for x in ref["plan"]]
    expected = [scene_name(i) for i in range(len(plan))]
    if model_src is not None:
        _copy_models(g, model_src, out / layout.MODELS_DIR)
    for s in expected:
        _place_scene(g, owner[s] / s, out / s, move=move)
    cfg_dict = json.loads(json.dumps(config if config is not None else ref.get("config", {})))
    cfg_dict.setdefault("output", {})["path"] = str(out.resolve())
    writers = open_writers(cfg_dict["output"], out, batch=True, sensor=sensor_for_config(cfg_dict))
    writers.start()
    for s in expected:
        writers.catch_up(out / s, scene_docs[s])
    written = writers.finish()
    record = {k: v for k, v in ref.items() if k not in ("stats",)}
    record["stats"] = merged_stats([r.get("stats") for r in runs], [scene_docs[s] for s in expected])
    record.update({
        "config": cfg_dict, "config_identity": config_identity(cfg_dict), "plan": plan, "seed": ref.get("seed"),
        "shard": [0, 1], "scenes": expected, "scenes_done": expected, "status": "complete",
        "merged_from": [{"dir": str(d), "shard": r.get("shard"), "stats": r.get("stats")}
                        for d, r in zip(shard_dirs, runs)],
    })
    reports = list(shard_reports)
    if reports:
        record["shard_reports"] = reports
    write_json_atomic(out / layout.RUN_FILE, record)
    summary = {"out": str(out), "scenes": len(expected), "images": sum(plan), "shards": len(shard_dirs)}
    if "bop" in written:
        summary["bop"] = {**written["bop"], "scenes": len(expected)}
    return summary


def merged_stats(shard_stats: list, scenes: list[dict]) -> dict:
    """run.json's stats of the merged run, as one process would have written them: `imports`,
    `seconds` and `steps` summed over the shards; `frames`, `physics` and `visib_fract` from the
    merged scenes' own records (scene.json), so they count each scene once."""
    measured: dict = {}
    for st in shard_stats:
        stats.add_measured(measured, st)
    return {**stats.rounded(measured), **stats.scene_stats(scenes)}


def _shard_runs(shard_dirs: list[Path]) -> list[dict]:
    """run.json of every shard; refuses folders that are no run, or runs of another plan, seed or preset."""
    if not shard_dirs:
        raise DataPipeError("merge: no shard folders given")
    runs = []
    for d in shard_dirs:
        rj = d / layout.RUN_FILE
        if not rj.is_file():
            raise DataPipeError(f"merge: {d} is not a DataPipe run folder (no run.json); "
                                "fix: give the --out folders of `datapipe run --shard i/n` runs")
        runs.append(read_json(rj))
    ref = runs[0]
    for d, r in zip(shard_dirs[1:], runs[1:]):
        for key in ("plan", "seed"):
            if r.get(key) != ref.get(key):
                raise DataPipeError(f"merge: {d} has a different {key} than {shard_dirs[0]} "
                                    f"({r.get(key)!r} vs {ref.get(key)!r}): shards of different runs cannot be merged")
        a = r.get("config_identity") or config_identity(r.get("config", {}))
        b = ref.get("config_identity") or config_identity(ref.get("config", {}))
        if a != b:
            raise DataPipeError(f"merge: {d} was made from a different preset than {shard_dirs[0]}; "
                                "fix: merge only shards of one run (same preset and --seed)")
    return runs


def _scene_owners(shard_dirs: list[Path], runs: list[dict], out: Path, plan: list[int]):
    """{scene name: the shard holding it complete}, and the problems: duplicates, scenes beyond the
    plan, scenes already in `out`, missing scenes (with the shard to re-run)."""
    expected = [scene_name(i) for i in range(len(plan))]
    owner: dict[str, Path] = {}
    duplicates: dict[str, list[str]] = {}
    unknown = []
    for d in shard_dirs:
        for sdir in layout.scene_dirs(d):
            if not layout.scene_complete(sdir):
                continue                     # a scene killed mid-way: not merged (reported as missing)
            if sdir.name not in expected:
                unknown.append(str(sdir))
            elif sdir.name in owner:
                duplicates.setdefault(sdir.name, [str(owner[sdir.name])]).append(str(d))
            else:
                owner[sdir.name] = d
    existing = [s for s in expected if (out / s).exists() and out.resolve() not in [d.resolve() for d in shard_dirs]]
    problems = []
    if duplicates:
        problems.append("duplicate scenes (complete in more than one shard): " + "; ".join(
            f"{s} in {', '.join(ds)}" for s, ds in sorted(duplicates.items())))
    if existing:
        problems.append(f"{out} already holds {', '.join(existing[:5])}{' ...' if len(existing) > 5 else ''}: "
                        "merge into an empty folder")
    if unknown:
        problems.append("scenes beyond the run's plan of "
                        f"{len(plan)} scenes: {', '.join(unknown[:5])}")
    missing = [s for s in expected if s not in owner]
    if missing:
        hints = [s + _rerun_hint(expected.index(s), len(plan), runs, shard_dirs) for s in missing]
        problems.append(f"{len(missing)} of {len(plan)} scenes missing: " + "; ".join(hints[:10])
                        + (" ..." if len(hints) > 10 else ""))
    return owner, problems


def _rerun_hint(i: int, n_scenes: int, runs: list[dict], shard_dirs: list[Path]) -> str:
    """Which shard makes scene i, and how to (re-)run it (when every shard split the run alike)."""
    counts = {tuple(r.get("shard") or (0, 1))[1] for r in runs}
    if len(counts) != 1:
        return ""
    given = {tuple(r.get("shard") or (0, 1)): d for r, d in zip(runs, shard_dirs)}
    n = next(iter(counts))
    group = _sequence_length(runs[0].get("config")) if runs else 1
    j = next(j for j in range(n) if i in shard_scenes(n_scenes, (j, n), group))
    if (j, n) in given:
        return f" (shard {j}/{n} in {given[(j, n)]}: re-run it with --resume)"
    return f" (shard {j}/{n}, not among the folders given: run it with --shard {j}/{n} --resume)"


def _image_id_problems(owner: dict[str, Path], scene_docs: dict[str, dict], plan: list[int]) -> list[str]:
    """Each scene's renders carry the run's global image ids (first_image[i] ...)."""
    expected = [scene_name(i) for i in range(len(plan))]
    first_image = [sum(plan[:i]) for i in range(len(plan))]
    problems = []
    for s, d in owner.items():
        i = expected.index(s)
        ids = [int(r["image_id"]) for r in scene_docs[s].get("renders", [])]
        if ids != list(range(first_image[i], first_image[i] + plan[i])):
            problems.append(f"{d / s}: image ids {ids} are not the run's ({first_image[i]}..{first_image[i] + plan[i] - 1})")
    return problems


def _model_source(shard_dirs: list[Path], problems: list[str]) -> Path | None:
    """The models/ folder to copy: the same meshes in every shard that has them (else a problem)."""
    model_src = None
    for d in shard_dirs:
        info = d / layout.MODELS_DIR / layout.MODELS_INFO
        if info.is_file():
            if model_src is None:
                model_src = d / layout.MODELS_DIR
            elif read_json(info) != read_json(model_src / layout.MODELS_INFO):
                problems.append(f"{d / layout.MODELS_DIR} differs from {model_src}: the shards used different meshes")
    return model_src


def _copy_models(g: guard.OutGuard | None, src: Path, dst: Path) -> None:
    if src.resolve() == dst.resolve():
        return
    if g is not None:
        g.move_tree(src, g.rel(dst), copy=True)
        return
    dst.mkdir(exist_ok=True)                    # no dir_fd here: by path (docs/OUTPUT_SAFETY.md)
    for p in sorted(src.iterdir()):
        if p.is_file() and not p.name.endswith(".tmp"):
            copy_atomic(p, dst / p.name)


def _place_scene(g: guard.OutGuard | None, src: Path, dst: Path, *, move: bool) -> None:
    """The scene folder `src` moved (or copied) to `dst` in OUT: file by file through OUT's handle
    (each recorded, as a one-process run records its files), the emptied folder removed."""
    if src.resolve() == dst.resolve():
        return
    if g is not None:
        g.move_tree(src, g.rel(dst), copy=not move)
        if move:
            try:
                os.rmdir(src)
            except OSError:
                pass                            # a temporary left out: stays with its shard
        return
    if move:
        os.replace(src, dst) if _same_fs(src, dst.parent) else shutil.move(str(src), str(dst))
    else:
        shutil.copytree(src, dst)


def _same_fs(a: Path, b: Path) -> bool:
    try:
        return os.stat(a).st_dev == os.stat(b).st_dev
    except OSError:                             # a vanished path: copy, never rename across devices
        return False


def _ray():                                      # the driver's: Ray only when --ray is asked for
    try:
        import ray
    except ImportError:
        raise DataPipeError("--ray needs the Ray package (fix: pip install 'datapipe[ray]' or "
                            "pip install 'ray[default]')") from None
    return ray


def run_distributed(preset_path: str | os.PathLike, out_dir: str | os.PathLike, *, address: str | None = None,
                    num_shards: int | None = None, seed: int | None = None, retries: int = 2,
                    extra_args: Sequence[str] = (), cpus_per_shard: float = 1.0, gpus_per_shard: float = 0.0,
                    runner: Sequence[str] | None = None, keep_shards: bool = False,
                    env: dict[str, str] | None = None, log: Callable[[str], None] | None = None,
                    blender_checks: bool = True, blender_session: Callable[[], ContextManager] | None = None,
                    warn: Callable[[list[str]], None] | None = None) -> dict:
    """Make the preset's dataset in `out_dir` with shards running as Ray tasks; returns a summary.

    address: a Ray cluster ("auto", "ray://host:10001", ...); None starts a local Ray instance with
    os.cpu_count() CPUs (an already initialised Ray is used as it is). num_shards: default one
    shard per scene, at most 4 per parallel slot. retries: re-runs of a failed shard (each resumes).
    cpus_per_shard/gpus_per_shard: Ray resources a shard reserves (Cycles itself uses every core
    of its machine unless render.threads is set). runner: the command that takes
    `PRESET --out DIR --shard i/n --seed S --resume` (default `<worker python> -m datapipe run`).
    env: extra environment variables for the runner processes.
    Before anything is written the preset goes through the gate (datapipe/engine/gate.py), as
    `datapipe run` does: blender_checks=False leaves out its Blender mesh preflight (a driver without
    bpy; each shard's `datapipe run` then refuses a broken mesh), blender_session is the context
    that preflight runs in, warn receives the gate's warnings (default: printed as the CLI does)."""
    say = log or (lambda m: print(m, file=sys.stderr, flush=True))
    cfg = config_mod.load(preset_path)
    if seed is not None:
        cfg.scene.seed = int(seed)
    out = Path(out_dir).resolve()
    report = gate.run_checks(cfg, blender=blender_checks, blender_session=blender_session,
                             folder=lambda _cfg: _check_out_dir(out))
    if warn is not None:
        warn(report.warnings)
    else:
        for w in report.warnings:
            say(f"datapipe: warning: {w}")
    s = cfg.scene
    plan = plan_scenes(s.num_renders, s.min_renders_per_scene, s.max_renders_per_scene, s.seed)
    shards_root = out / SHARDS_DIR
    # one run per output folder (a one-process run into it is refused meanwhile); the driver's own
    # files (OUT/_shards/) written through OUT's handle, not recorded: dropped after the merge
    with outdir.OutLock(out), guard.guarding(out):
        make_dirs(shards_root)
        preset = _write_shard_preset(cfg, shards_root)
        spec = {"preset": str(preset), "seed": cfg.scene.seed, "extra_args": list(extra_args),
                "runner": list(runner) if runner else None, "env": dict(env or {}), "out": str(out)}
        dirs, reports = _run_shards_on_ray(spec, plan, shards_root, address=address, num_shards=num_shards,
                                           retries=retries, cpus_per_shard=cpus_per_shard,
                                           gpus_per_shard=gpus_per_shard, say=say,
                                           group=sequence_length(cfg))
        for d in dirs:
            if not d.is_dir():
                raise DataPipeError(f"{d} is not visible on this machine: the output folder must be on a filesystem "
                                    "that every Ray node mounts at the same path")
        reports.sort(key=lambda r: r["shard"][0])
        manifest = Manifest.load(out) or Manifest(out)    # the merged run's, as a one-process run's
        try:
            summary = merge_shards(dirs, out, move=True, config=cfg.to_dict(), shard_reports=reports,
                                   manifest=manifest)
            with manifest.writing() as g:                  # the logs and the sheets are the run's files too
                _keep_logs(g, shards_root, out / "logs", drop_shards=not keep_shards)
                summary["attempts"] = {r["shard"][0]: r["attempts"] for r in reports}
                say(f"ray: merged {summary['scenes']} scenes ({summary['images']} renders) from {len(dirs)} "
                    f"shard(s) into {out}")
                if "bop" in summary:
                    say(f"ray: BOP dataset written to {out / layout.BOP_DIR}")
                from ..show import overview_after_run
                overview = overview_after_run(out, cfg.output)
                if overview is not None:
                    summary["overview"] = str(overview)
                manifest.update()
        finally:
            manifest.close()
    return summary


def _check_out_dir(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise DataPipeError(f"output: {out} exists and is not a folder (fix: choose a folder path)")
    if out.is_dir() and any(p.name.startswith(layout.SCENE_PREFIX) for p in out.iterdir()):
        raise DataPipeError(f"output: {out} already holds scenes (fix: choose an empty folder; a distributed "
                            f"run resumes from {out / SHARDS_DIR} when re-run into the same folder)")
    outdir.refuse_links(out)                    # the merge writes the run's layout here ...
    outdir.refuse_links_under(out, SHARDS_DIR)  # ... and the shards run in here


def _write_shard_preset(cfg, shards_root: Path) -> Path:
    """The preset every shard runs: native only (BOP is written once, at the merge), no overview."""
    shard_cfg = cfg.copy()
    shard_cfg.output.formats = ["native"]
    shard_cfg.output.overview = False
    shard_cfg.output.path = str(shards_root)
    preset = shards_root / SHARD_PRESET
    config_mod.save(shard_cfg, preset)
    return preset


def _sequence_length(config: dict | None) -> int:
    """Scenes per pile of a run's recorded config: shards hold whole pick sequences (draws/picks.py)."""
    try:
        return sequence_length(config_mod.Config.from_dict(config or {}))
    except (DataPipeError, TypeError, ValueError, ZeroDivisionError):
        return 1


def _run_shards_on_ray(spec: dict, plan: list[int], shards_root: Path, *, address, num_shards, retries,
                       cpus_per_shard, gpus_per_shard, say, group: int = 1) -> tuple[list[Path], list[dict]]:
    """Start (or join) Ray, run one task per shard (a pick sequence's `group` of scenes in one), wait
    for all; returns (shard folders, reports). DataPipeError naming the failed shards' logs."""
    ray = _ray()
    started = False
    if not ray.is_initialized():
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=os.cpu_count() or 1, include_dashboard=False, log_to_driver=False)
        started = True
    try:
        slots = max(1, int(ray.cluster_resources().get("CPU", 1) // max(cpus_per_shard, 1e-6)))
        n = num_shards or min(len(plan), 4 * slots)
        n = max(1, min(int(n), -(-len(plan) // group)))
        # an earlier interrupted run with another shard count cannot be resumed shard by shard
        old = [p for p in shards_root.glob("shard_*") if p.is_dir() and not p.name.endswith(f"_of_{n:04d}")]
        if old:
            raise DataPipeError(f"{shards_root} holds shards of a split into a different number of shards "
                                f"({old[0].name}); fix: re-run with the same --shards, or delete {shards_root}")
        say(f"ray: {len(plan)} scenes ({sum(plan)} renders) in {n} shard(s) on {slots} slot(s), "
            f"seed {spec['seed']}, retries {retries}")
        task = ray.remote(run_shard).options(max_retries=int(retries), retry_exceptions=True,
                                             num_cpus=cpus_per_shard, num_gpus=gpus_per_shard)
        dirs = [shards_root / shard_dir_name(i, n) for i in range(n)]
        refs = {task.remote({**spec, "shard_dir": str(d), "shard": (i, n),
                             "scenes": [scene_name(k) for k in shard_scenes(len(plan), (i, n), group)]}): i
                for i, d in enumerate(dirs)}
        reports, failures = _wait_for_shards(ray, refs, n, retries, say)
        if failures:
            raise DataPipeError(f"{len(failures)} of {n} shard(s) failed after {retries + 1} attempt(s) each: "
                                + "; ".join(f"shard {i}/{n} (log {shards_root / (shard_dir_name(i, n) + '.log')})"
                                            for i, _ in failures)
                                + ". Finished shards are kept: run the same command again to resume.")
    finally:
        if started:
            ray.shutdown()
    return dirs, reports


def _wait_for_shards(ray, refs: dict, n: int, retries: int, say) -> tuple[list[dict], list[tuple[int, str]]]:
    reports, failures = [], []
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        i = refs[ready[0]]
        try:
            rep = ray.get(ready[0])
            reports.append(rep)
            say(f"ray: shard {i}/{n} done on {rep['host']} ({len(rep['scenes'])} scenes, "
                f"{rep['seconds']:.1f} s, attempt {rep['attempts']})")
        except Exception as e:  # RayTaskError wrapping the last attempt's error, or a lost worker
            msg = str(e).strip().splitlines()
            failures.append((i, msg[-1] if msg else repr(e)))
            say(f"ray: shard {i}/{n} FAILED after {retries + 1} attempt(s): {msg[-1] if msg else e}")
    return reports, failures


def _keep_logs(g: guard.OutGuard | None, shards_root: Path, logs: Path, *, drop_shards: bool) -> None:
    """Move the shard logs (the runner's terminal output, SHARD.log, and Blender's own output,
    SHARD/blender.log as SHARD.blender.log) into OUT/logs (through OUT's handle, recorded by path:
    their bytes say when the run ran, as blender.log's); drop the emptied shard folders unless
    asked to keep them (rmtree never follows a link)."""
    moves = [(p.parent, p.name, p.name) for p in sorted(shards_root.glob("*.log"))]
    moves += [(p.parent, p.name, f"{p.parent.name}.{layout.BLENDER_LOG}")
              for p in sorted(shards_root.glob(f"*/{layout.BLENDER_LOG}"))]
    if g is None:                               # no dir_fd here: by path (docs/OUTPUT_SAFETY.md)
        logs.mkdir(exist_ok=True)
        for folder, name, dst in moves:
            os.replace(folder / name, logs / dst)
    else:
        g.make_dirs(logs)
        for folder, name, dst in moves:
            src = g.open_source(folder)
            try:
                g.move_in(src, name, f"{g.rel(logs)}/{dst}", by_path=True)
            finally:
                os.close(src)
    if drop_shards:
        shutil.rmtree(shards_root, ignore_errors=True)
