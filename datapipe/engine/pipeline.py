"""The run loop: Config -> scenes -> renders -> files. A generator of Progress events, so the same loop
runs in a plain `for` headless and step by step under a timer in the UI.

Everything a scene does is derived from (base seed, scene index): a killed run resumes to the same
dataset, and shards (`shard=(i, n)`) produce the same scenes as one process would.

The loop owns the run (folders, resume, cancel, shards, run.json, annotations, writers); what is
rendered comes from a world (core/world.py) made by `world(cfg, out)`, by default the Blender one,
built only when there is something to render. Tests pass a fake world (tests/fake_world.py).

With `scene.picks` a pile's pick steps are the scenes after it (datapipe/draws/picks.py), made in one
go by `_make_sequence`: shards hold whole sequences, and --resume replays the complete steps of a
pile (simulation only) before making the rest.
"""
from __future__ import annotations

import functools
import time
from pathlib import Path
from typing import Callable, ContextManager, Iterator

import numpy as np

from ..version import __version__
from ..io import outdir
from . import gate
from ..config import Config
from ..errors import DataPipeError
from . import progress, stats
from ..checks.physics_check import physics_line, totals_line
from .progress import Progress, Tracker, fmt_s
from ..checks.quality import render_warnings
from ..io import layout, native
from ..io.files import make_dirs, read_json, write_json_atomic
from ..io.bop_models import models_symmetries
from ..io.models import write_models
from ..io.legacy import LegacyPickleWriter
from ..io.bop_sensor import sensor_for_config
from ..io.writers import Writers, open_writers
from ..visibility import visible_fractions
from ..draws import picks
from ..draws.seeds import plan_scenes, render_seed, scene_rng, scene_seed, seed_python, shard_scenes
from ..core.world import BlenderWorld
from ..world import SILENT, Reporter, World

class QualityError(DataPipeError):
    """--strict: a render failed a quality gate (datapipe.checks.quality)."""


STAGES = ("placement", "simulation", "render", "structured_light", "write")


def _config_identity(cfg: Config) -> dict:
    return layout.config_identity(cfg.to_dict())


class Pipeline:
    def __init__(self, cfg: Config, out_dir: str | Path | None = None, *, resume: bool = False,
                 force: bool = False, shard: tuple[int, int] = (0, 1), seed: int | None = None,
                 strict: bool = False, world: Callable[[Config, Path], World] = BlenderWorld,
                 on_step: Callable[[Progress], None] | None = None, heartbeat_s: float = progress.HEARTBEAT_S):
        """`on_step`: receives the lines inside a scene (datapipe/engine/progress.py), at least every
        `heartbeat_s` seconds while a step lasts, possibly from the heartbeat thread."""
        self.cfg = cfg.copy()
        self.on_step, self.heartbeat_s = on_step, heartbeat_s
        self.tracker: Tracker | None = None
        self.make_world = world
        if seed is not None:
            self.cfg.scene.seed = seed
        self.out = Path(out_dir if out_dir is not None else self.cfg.output.path).resolve()
        self.cfg.output.path = str(self.out)
        self.resume, self.force, self.shard, self.strict = resume, force, shard, strict
        self.report: gate.CheckReport | None = None      # the first full pass of check()
        self._cancel = False
        self._t_start = self._t_loop = 0.0
        self._made = 0                # renders made in this call (for the ETA)
        # this call's work; run.json's stats add the earlier calls' (resume) and every scene's simulation
        self.stats: dict = {"imports": 0, "seconds": {k: 0.0 for k in STAGES}}
        self.stats["seconds"]["setup"] = 0.0
        self._earlier_stats: dict = {}
        self._render_device: str | None = None      # the Cycles backend that renders (render.device GPU only)
        self._setup_step: dict = {}                 # the world's setup, as stats.steps counts a step
        self._scenes: dict[str, dict] = {}          # scene name -> its record (simulation, renders' visib_fract)
        self._models: dict = {}

    # -- the plan: drawn on first use (check() refuses bad bounds before run() draws it) --------------
    @functools.cached_property
    def plan(self) -> list[int]:
        """Renders per scene."""
        s = self.cfg.scene
        return plan_scenes(s.num_renders, s.min_renders_per_scene, s.max_renders_per_scene, s.seed)

    @functools.cached_property
    def sequence_length(self) -> int:
        """Scenes per pile: 1, or a pick sequence's drop and steps (datapipe/draws/picks.py)."""
        return picks.sequence_length(self.cfg)

    @functools.cached_property
    def scene_ids(self) -> list[int]:
        return shard_scenes(len(self.plan), self.shard, group=self.sequence_length)

    @functools.cached_property
    def first_image_id(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self.plan)]).astype(int)

    @functools.cached_property
    def total(self) -> int:
        """Renders this call makes at most (its shard's)."""
        return int(sum(self.plan[i] for i in self.scene_ids))

    # -- checks before any Blender work ----------------------------------------------------------
    def check(self, blender_session: Callable[[], ContextManager] | None = None) -> gate.CheckReport:
        """The gate (datapipe/engine/gate.py): config rules, this run's output folder, the mesh
        preflight (with the Blender world), part fit, device, memory. Raises ConfigError /
        DataPipeError; writes nothing. The first pass checks everything; later ones (under the
        run's lock, at run()) only the rules and the folder, which may have changed meanwhile.
        `blender_session`: the context the mesh preflight runs in (gate.run_checks; the CLI's log)."""
        again = self.report is not None
        report = gate.run_checks(self.cfg, blender=getattr(self.make_world, "imports_meshes", False),
                                 folder=self._check_folder, blender_session=blender_session,
                                 inputs=not again)
        if not again:
            self.report = report
        return report

    def _check_folder(self, cfg: Config) -> None:
        """The gate's folder step: the output folder's refusals (datapipe/io/outdir.py)."""
        self.cfg = cfg                                # validated, one entry per object of a BOP folder
        if self.out.exists() and not self.out.is_dir():
            raise DataPipeError(f"output: {self.out} exists and is not a folder (fix: choose a folder path)")
        outdir.refuse_links(self.out)
        if self.out.is_dir() and outdir.meaningful_entries(self.out):
            run_file = self.out / layout.RUN_FILE
            if self.resume:
                earlier = outdir.Manifest.load(self.out)
                if not run_file.is_file() and not (earlier is not None and earlier.only_itself()):
                    raise DataPipeError(f"output: cannot resume {self.out}: it has no {layout.RUN_FILE} "
                                        "(fix: choose the folder of an earlier DataPipe run, or an empty folder)")
                prev = outdir.read_record(run_file, "run record") if run_file.is_file() else None
                if prev is not None and prev.get("config_identity") != _config_identity(self.cfg):
                    raise DataPipeError(f"output: {self.out} holds a run of a different preset or seed "
                                        "(fix: resume with the same preset and --seed, or choose another folder)")
                base = self.cfg.scene.seed
                scenes = {layout.scene_name(i): (i, scene_seed(base, i)) for i in self.scene_ids}
                # the scenes --resume makes (again): every file it writes there must be its own
                to_write = [n for n in scenes if not _complete_with_files(self.out / n)]
            else:
                if not self.force:
                    raise DataPipeError(f"output: {self.out} is not empty (fix: pass --resume to continue that "
                                        "run, or choose an empty folder; nothing was written)")
                earlier = outdir.check_force(self.out)
                scenes = {name: (i, None) for name, i in outdir.scene_folders(self.out).items()}
                to_write = [layout.scene_name(i) for i in self.scene_ids]
            outdir.refuse_foreign_scenes(self.out, scenes)
            if self.resume and self.cfg.output.legacy_pickle and (self.out / layout.LEGACY_PICKLE).is_file():
                LegacyPickleWriter(self.out).start()        # refuses a pickle that is not the run's
            outdir.refuse_collisions(self.out, earlier, to_write)

    def cancel(self) -> None:
        """Stop after the render in progress; everything written so far stays."""
        self._cancel = True

    # -- the loop -----------------------------------------------------------------------------------
    def run(self) -> Iterator[Progress]:
        self.check()
        self._t_start = time.perf_counter()
        kept = None
        if self.force and self.out.is_dir() and not self.resume and outdir.meaningful_entries(self.out):
            removed, kept = outdir.remove_run_files(outdir.check_force(self.out))   # only the earlier run's own
        self.out.mkdir(parents=True, exist_ok=True)
        if self.resume:
            earlier = self._run_record().get("stats")
            self._earlier_stats = earlier if isinstance(earlier, dict) else {}
        self.manifest = (outdir.Manifest.load(self.out) if self.resume else None) or outdir.Manifest(self.out)
        try:
            with self.manifest.writing():      # every write under OUT: through its handle, recorded
                if kept is not None:
                    yield Progress("force", 0, self.total, message=_force_line(removed, kept))
                yield from self._run()
        finally:
            self.manifest.close()

    def _run(self) -> Iterator[Progress]:
        self.manifest.update()
        self._write_run_file(status="running")
        self.manifest.update()
        writers = open_writers(self.cfg.output, self.out, sensor=sensor_for_config(self.cfg.to_dict()))
        writers.start()
        done, todo = 0, []
        for i in self.scene_ids:
            sdir = self.out / layout.scene_name(i)
            scene = layout.read_scene(sdir) if self.resume else None
            if scene is not None and scene.get("complete", False) and _files_present(sdir, scene):
                done += self.plan[i]
                self._scenes[scene["name"]] = scene
                # the commit protocol: scene.json is written first; a crash before the other outputs and
                # run.json's scenes_done leaves them to be repaired here
                writers.catch_up(sdir, scene)
                self._mark_scene_done(i)
                yield Progress("skip", done, self.total, scene=i, message="already complete")
            else:
                todo.append(i)
        if not todo:
            yield from self._finished(writers, done, "nothing to do: every scene is complete")
            return
        yield Progress("setup", done, self.total, message="setting up Blender scene")
        world = self._build_world()
        # the tracker also times the steps for run.json (wall and CPU), so it runs without a sink too
        self.tracker = Tracker(self.on_step or _no_lines, self.heartbeat_s)
        if self.on_step is not None:
            self.tracker.start()
        world.report_to(self.tracker)
        try:
            for note in world.setup_notes:
                yield Progress("setup", done, self.total, message=note)
            for first, steps in self._sequences(todo):
                if self._cancel:
                    yield from self._cancelled(done, steps[0])
                    return
                done = yield from self._make_sequence(world, writers, first, steps, done)
                if self._cancel:
                    yield from self._cancelled(done, steps[-1])
                    return
        finally:
            world.report_to(SILENT)
            if self.tracker is not None:
                self.tracker.stop()
            world.close()
        yield from self._finished(writers, done, f"finished {self._made} render(s) in "
                                                 f"{fmt_s(time.perf_counter() - self._t_start)}; "
                                                 f"{totals_line(self.run_stats()['physics'])}")

    @property
    def _progress(self) -> Reporter:
        """Where the run loop's own steps (annotate, the scene's files) are reported: the run's tracker."""
        return self.tracker if self.tracker is not None else SILENT

    def _build_world(self) -> World:
        t0, c0 = time.perf_counter(), time.process_time()
        world = self.make_world(self.cfg, self.out)
        try:
            world.setup()
            meshes = world.model_meshes()
            write_models(self.out / layout.MODELS_DIR, meshes, symmetries=models_symmetries(self.cfg, meshes))
        except BaseException:
            world.close()
            raise
        self.stats["seconds"]["setup"] = time.perf_counter() - t0
        self._setup_step = {"wall_s": self.stats["seconds"]["setup"], "cpu_s": time.process_time() - c0, "n": 1}
        self.stats["imports"] = world.import_count
        if self.cfg.render.device == "GPU":          # which backend that was, or CPU where no GPU was found
            self._render_device = getattr(getattr(world, "renderer", None), "device", None)
        # the models in mm, for the visible fractions (datapipe/visibility.py)
        self._models = {k: (np.asarray(m[0], dtype=np.float64) * 1000.0, m[1]) for k, m in meshes.items()}
        self._t_loop = time.perf_counter()
        return world

    def _sequences(self, todo: list[int]) -> list[tuple[int, list[int]]]:
        """(first scene of the pile, its scenes to make) in run order: one scene per pile without
        scene.picks; with it, the steps of a pick sequence to make together (datapipe/draws/picks.py)."""
        out: dict[int, list[int]] = {}
        for i in todo:
            out.setdefault(picks.pile_of(i, self.sequence_length)[0], []).append(i)
        return list(out.items())

    def _make_sequence(self, world: World, writers: Writers, first: int, steps: list[int], done: int):
        """Make the scenes `steps` of the pile that starts at scene `first` (a generator of Progress;
        returns the new `done`). Without scene.picks that is the one scene, dropped. With it, the pile
        is dropped, then each step removes parts (draws/picks.py) and lets the rest settle; a step
        --resume finds complete is replayed (drop and settles, each deterministic, no render), so the
        steps after it start from the same pile."""
        base = self.cfg.scene.seed
        pk = self.cfg.scene.picks
        start, last, finished = None, max(steps), False
        for i in range(first, last + 1):
            seed_python(base, i)
            if i == first:
                record = None if pk is None else {"pile": layout.scene_name(first), "step": 0, "parent": None,
                                                  "order": pk.order, "removed": []}
                message = "dropping parts"
                make = functools.partial(world.start_scene, i, base, scene_rng(base, i), self.plan[i])
            else:
                remove = self._pick(i, start)
                record = {"pile": layout.scene_name(first), "step": i - first, "parent": layout.scene_name(i - 1),
                          "order": pk.order, "removed": remove}
                message = f"picking {len(remove)} part(s), the rest settling"
                make = functools.partial(world.pick_step, i, base, scene_rng(base, i), self.plan[i], remove)
            if i in steps:
                done, start = yield from self._make_scene(world, writers, i, done, make, message, record,
                                                          finish=i == last)
                finished = i == last or self._cancel
            else:
                yield Progress("scene", done, self.total, scene=i, message=f"{message} (complete: replayed, "
                                                                           "not rendered)")
                start = make()
                for k, v in start.seconds.items():
                    self.stats["seconds"][k] += v
            if self._cancel:
                break
        if not finished:                   # cancelled while a complete step was replayed
            world.finish_scene()
        return done

    def _pick(self, i: int, start) -> list[str]:
        """The parts step scene `i` removes from the pile of the step before (`start`: its SceneStart)."""
        pk = self.cfg.scene.picks
        names = [p.name for p in start.parts]
        heights = visible = None
        if pk.order == "top":
            heights = picks.top_heights(start.poses, [self._models[p.obj_id][0] / 1000.0 for p in start.parts])
        elif pk.order == "visible":        # the mean over the previous step's renders (its scene record)
            seen: dict[str, list[float]] = {}
            for rd in self._scenes[layout.scene_name(i - 1)]["renders"]:
                for o in rd["objects"]:
                    seen.setdefault(o["name"], []).append(float(o.get("visib_fract") or 0.0))
            visible = np.array([np.mean(seen.get(n, [0.0])) for n in names])
        return picks.choose(pk.order, names, picks.step_count(len(names), self.cfg), heights=heights,
                            visible=visible, rng=picks.pick_rng(self.cfg.scene.seed, i))

    def _make_scene(self, world: World, writers: Writers, i: int, done: int, make: Callable, message: str,
                    record: dict | None, finish: bool = True):
        """Drop (or pick and settle: `make`), render and write scene i (a generator of Progress;
        returns the new `done` and the scene's SceneStart). `record`: scene.json's "picks";
        `finish`: the world's scene ends here (not before a pick sequence's next step, unless cancelled)."""
        sdir = self.out / layout.scene_name(i)
        # a scene killed mid-way is made again over its files (same names: each write replaces one);
        # nothing else in the folder is touched (a file of yours there stays, beside the run's)
        make_dirs(sdir)
        yield Progress("scene", done, self.total, scene=i, message=message)
        base = self.cfg.scene.seed
        self._track(done, i, None)
        start = make()
        for k, v in start.seconds.items():
            self.stats["seconds"][k] += v
        scene = native.scene_record(i, scene_seed(base, i), start)
        if record is not None:
            scene["picks"] = record
        self._scenes[scene["name"]] = scene            # filled below; a scene made again replaces its record
        for r, pose_index in enumerate(start.pose_indices):
            seed = render_seed(base, i, r)
            rdir = sdir / layout.render_name(r)
            make_dirs(rdir)
            self._track(done, i, r)
            view = world.render(rdir, pose_index, seed, scene_id=i, render_id=r, base_seed=base)
            self._progress.begin("annotate", f"{len(start.parts)} parts")
            scene["renders"].append(native.render_record(r, int(self.first_image_id[i] + r), pose_index, seed,
                                                         view, start.parts, sdir))
            visible_fractions(scene["renders"][-1]["objects"], view.mask, view.K, self._models, *view.resolution,
                              dist=view.distortion)
            for k, v in view.seconds.items():
                self.stats["seconds"][k] += v
            done += 1
            self._made += 1
            rate = (time.perf_counter() - self._t_loop) / self._made
            secs = {**start.seconds, **view.seconds} if r == 0 else view.seconds
            warnings = self._quality_gate(i, r, view, scene, scene["renders"][-1])
            if self.tracker is not None:
                self.tracker.render_done()
            yield Progress("render", done, self.total, scene=i, render=r,
                           elapsed=time.perf_counter() - self._t_start, eta=rate * (self.total - done),
                           seconds=secs, message="rendered" + "".join(f" [warning: {w}]" for w in warnings))
            if self._cancel:
                break
        t0 = time.perf_counter()
        if self.tracker is not None:        # the scene's renders are done: [done/total], no render in progress
            self.tracker.at(done=done, total=self.total, scene=i, render=None,
                            per_render=(time.perf_counter() - self._t_loop) / self._made if self._made else None,
                            renders_after=self.total - done)
        self._progress.begin("write", "scene files")
        scene["complete"] = complete = len(scene["renders"]) == self.plan[i]
        if complete:
            writers.add_scene(sdir, scene)
        else:
            native.write_scene(sdir, scene)     # the record of a cancelled scene (not complete)
        if finish or self._cancel:
            world.finish_scene()
        self._progress.end()
        self.stats["seconds"]["write"] += time.perf_counter() - t0
        self.manifest.update()
        if complete:
            self._mark_scene_done(i)
            yield Progress("scene_done", done, self.total, scene=i, elapsed=time.perf_counter() - self._t_start,
                           message=physics_line({"parts": len(scene["objects"]), **scene["simulation"]}))
        return done, start

    def _track(self, done: int, scene: int, render: int | None) -> None:
        """Tell the step tracker where the run is (the render `done` + 1 is in progress)."""
        if self.tracker is not None:
            per_render = (time.perf_counter() - self._t_loop) / self._made if self._made else None
            self.tracker.at(done=done, total=self.total, scene=scene, render=render, per_render=per_render,
                            renders_after=self.total - done - 1)

    def _finished(self, writers: Writers, done: int, message: str) -> Iterator[Progress]:
        writers.finish()
        self._write_run_file(status="complete")
        self.manifest.update()
        yield Progress("done", done, self.total, elapsed=time.perf_counter() - self._t_start, message=message)

    def _cancelled(self, done: int, scene: int) -> Iterator[Progress]:
        self._write_run_file(status="cancelled")
        self.manifest.update()
        yield Progress("cancelled", done, self.total, scene=scene, elapsed=time.perf_counter() - self._t_start,
                       message="cancelled: everything written so far is kept; --resume continues")

    # -- quality gates ----------------------------------------------------------------------------
    def _quality_gate(self, i: int, r: int, view, scene: dict, rec: dict) -> list[str]:
        """Warnings of one render (datapipe.checks.quality), kept in run.json; with strict=True an error."""
        sl_info = rec.get("structured_light") or {}
        warnings = render_warnings(
            rgb=view.rgb, visible_px=[o["px_count_visib"] for o in rec["objects"]],
            sl_valid_fraction=sl_info.get("valid_fraction"),
            parts_dropped=len(scene["objects"]) + len(scene["simulation"]["removed"]),
            parts_lost=len(scene["simulation"]["removed"]))
        if not warnings:
            return []
        where = f"{layout.scene_name(i)}/{layout.render_name(r)}"
        rec_run = self._run_record()
        kept = [w for w in rec_run.get("warnings", []) if w.get("render") != where]    # a remade render
        rec_run["warnings"] = kept + [{"render": where, "warning": w} for w in warnings]
        write_json_atomic(self.out / layout.RUN_FILE, rec_run)
        if self.strict:
            self._write_run_file(status="failed")
            raise QualityError(f"{where}: {warnings[0]} (fix: correct the preset as the warning says, or run "
                               "without --strict to keep such renders; --resume continues after the fix only "
                               "with the same preset, so start a new --out)")
        return warnings

    # -- run.json ---------------------------------------------------------------------------------
    def _run_record(self) -> dict:
        path = self.out / layout.RUN_FILE
        return read_json(path) if path.is_file() else {}

    def _write_run_file(self, status: str) -> None:
        rec = self._run_record()
        rec.update({
            "datapipe_version": __version__,
            "config": self.cfg.to_dict(),
            "config_identity": _config_identity(self.cfg),
            "seed": self.cfg.scene.seed,
            "plan": self.plan,
            "shard": list(self.shard),
            "scenes": [layout.scene_name(i) for i in self.scene_ids],
            "status": status,
            "stats": self.run_stats(),
        })
        rec.setdefault("scenes_done", [])
        if self._render_device is not None:
            rec["render_device"] = self._render_device
        write_json_atomic(self.out / layout.RUN_FILE, rec)

    def run_stats(self) -> dict:
        """run.json's stats, for the whole run however many calls (--resume) made it: `frames`,
        `physics` and `visib_fract` from the records of every scene made so far (a scene made again
        counts once); `imports`, `seconds` and `steps` (wall and CPU seconds and count of each step
        of datapipe/engine/progress.py, and the world's `setup`) this call's work plus what the earlier
        calls' run.json recorded."""
        steps = dict(self.tracker.totals()) if self.tracker is not None else {}
        if self._setup_step:
            steps["setup"] = self._setup_step
        measured = stats.add_measured({}, self._earlier_stats)
        stats.add_measured(measured, {"imports": self.stats["imports"], "seconds": self.stats["seconds"],
                                      "steps": steps})
        measured["seconds"] = {k: measured["seconds"][k] for k in self.stats["seconds"]}   # this run's stages
        return {**stats.rounded(measured), **stats.scene_stats(self._scenes[n] for n in sorted(self._scenes))}

    def _mark_scene_done(self, i: int) -> None:
        rec = self._run_record()
        done = set(rec.get("scenes_done", []))
        done.add(layout.scene_name(i))
        rec["scenes_done"] = sorted(done)
        rec["stats"] = self.run_stats()
        write_json_atomic(self.out / layout.RUN_FILE, rec)


def _no_lines(_: Progress) -> None:
    """The step sink of a run without progress lines (the tracker still times the steps)."""


def _force_line(removed: int, kept: list[str]) -> str:
    """What --force removed and kept (every file it did not write, whatever its name)."""
    line = f"--force: removed {removed} file(s) the earlier run wrote"
    if not kept:
        return line + "; nothing else was in the folder"
    more = f" and {len(kept) - 10} more" if len(kept) > 10 else ""
    return line + f"; kept {len(kept)} it did not write (or that changed since): {', '.join(kept[:10])}{more}"


def _complete_with_files(sdir: Path) -> bool:
    """A scene --resume skips: complete, with every file its renders list."""
    scene = layout.read_scene(sdir)
    return scene is not None and bool(scene.get("complete", False)) and _files_present(sdir, scene)


def _files_present(sdir: Path, scene: dict) -> bool:
    """Every file the scene's renders list is on disk (a complete scene.json alone is not enough)."""
    try:
        return all((sdir / rel).is_file() for rd in scene["renders"] for rel in rd["files"].values())
    except (KeyError, TypeError, AttributeError):
        return False
