"""The run loop: Config -> scenes -> renders -> files. A generator of Progress events, so the same loop
runs in a plain `for` headless and step by step under a timer in the UI.

Everything a scene does is derived from (base seed, scene index): a killed run resumes to the same
dataset, and shards (`shard=(i, n)`) produce the same scenes as one process would.
"""
from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import __version__, outdir
from ..config import Config
from ..errors import DataPipeError
from ..quality import render_warnings
from ..seeds import plan_scenes, render_seed, scene_rng, scene_seed, seed_python, shard_scenes
from ..io import layout
from ..physics_check import add_to_totals, physics_line, totals_line
from ..io.files import read_json, write_json_atomic
from ..io.models import write_models
from ..io.native import write_scene
from ..io.writers import open_writers

class QualityError(DataPipeError):
    """--strict: a render failed a quality gate (datapipe.quality)."""


STAGES = ("placement", "simulation", "render", "structured_light", "write")


@dataclass
class Progress:
    stage: str                 # setup | scene | render | scene_done | skip | done | cancelled
    done: int                  # renders finished in this run (skipped-complete scenes included)
    total: int                 # renders this run (this shard) makes
    scene: int | None = None
    render: int | None = None
    elapsed: float = 0.0
    eta: float | None = None
    seconds: dict = field(default_factory=dict)    # per-stage seconds of the last render / scene
    message: str = ""

    def line(self) -> str:
        eta = f", ETA {_fmt_s(self.eta)}" if self.eta is not None else ""
        stages = ", ".join(f"{k} {v:.2f}s" for k, v in self.seconds.items() if v > 0)
        stages = f" ({stages})" if stages else ""
        where = ""
        if self.scene is not None:
            where = f" {layout.scene_name(self.scene)}"
            if self.render is not None:
                where += f"/{layout.render_name(self.render)}"
        return f"[{self.done}/{self.total}]{where} {self.message}{stages}{eta}".rstrip()


def _fmt_s(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else (f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s")


def _config_identity(cfg: Config) -> dict:
    return layout.config_identity(cfg.to_dict())


class Pipeline:
    def __init__(self, cfg: Config, out_dir: str | Path | None = None, *, resume: bool = False,
                 force: bool = False, shard: tuple[int, int] = (0, 1), seed: int | None = None,
                 strict: bool = False):
        self.cfg = cfg.copy()
        if seed is not None:
            self.cfg.scene.seed = seed
        self.out = Path(out_dir if out_dir is not None else self.cfg.output.path).resolve()
        self.cfg.output.path = str(self.out)
        self.resume, self.force, self.shard, self.strict = resume, force, shard, strict
        s = self.cfg.scene
        self.plan = plan_scenes(s.num_renders, s.min_renders_per_scene, s.max_renders_per_scene, s.seed)
        self.scene_ids = shard_scenes(len(self.plan), shard)
        self.first_image_id = np.concatenate([[0], np.cumsum(self.plan)]).astype(int)
        self.total = int(sum(self.plan[i] for i in self.scene_ids))
        self._cancel = False
        self.stats: dict = {"imports": 0, "frames": {}, "seconds": {k: 0.0 for k in STAGES}, "physics": {}}
        self.stats["seconds"]["setup"] = 0.0

    # -- checks before any Blender work ----------------------------------------------------------
    def check(self) -> None:
        """Raise ConfigError/DataPipeError for bad input or a refused output folder. Writes nothing."""
        self.cfg.validate()
        if self.out.exists() and not self.out.is_dir():
            raise DataPipeError(f"output: {self.out} exists and is not a folder (fix: choose a folder path)")
        if self.out.is_dir() and outdir.meaningful_entries(self.out):
            run_file = self.out / layout.RUN_FILE
            if self.resume:
                if not run_file.is_file():
                    raise DataPipeError(f"output: cannot resume {self.out}: it has no {layout.RUN_FILE} "
                                        "(fix: choose the folder of an earlier DataPipe run, or an empty folder)")
                prev = outdir.read_record(run_file, "run record")
                if prev.get("config_identity") != _config_identity(self.cfg):
                    raise DataPipeError(f"output: {self.out} holds a run of a different preset or seed "
                                        "(fix: resume with the same preset and --seed, or choose another folder)")
            elif self.force:
                outdir.check_force(self.out)
            else:
                raise DataPipeError(f"output: {self.out} is not empty (fix: pass --resume to continue that run, "
                                    "or choose an empty folder; nothing was written)")

    def cancel(self) -> None:
        """Stop after the render in progress; everything written so far stays."""
        self._cancel = True

    # -- the loop -----------------------------------------------------------------------------------
    def run(self) -> Iterator[Progress]:
        self.check()
        t_start = time.perf_counter()
        if self.force and self.out.is_dir() and not self.resume and outdir.meaningful_entries(self.out):
            outdir.check_force(self.out).remove_listed()      # only the earlier run's own files
        self.out.mkdir(parents=True, exist_ok=True)
        self.manifest = outdir.Manifest.start(self.out, resume=self.resume)
        self._write_run_file(status="running")
        self.manifest.update()
        writers = open_writers(self.cfg.output, self.out)
        writers.start()

        done = 0
        todo = []
        for i in self.scene_ids:
            sdir = self.out / layout.scene_name(i)
            scene = layout.read_scene(sdir) if self.resume else None
            if scene is not None and scene.get("complete", False) and _files_present(sdir, scene):
                done += self.plan[i]
                # the commit protocol: scene.json is written first; a crash before the other outputs and
                # run.json's scenes_done leaves them to be repaired here
                writers.catch_up(sdir, scene)
                self._mark_scene_done(i)
                yield Progress("skip", done, self.total, scene=i, message="already complete")
            else:
                todo.append(i)
        if not todo:
            writers.finish()
            self._write_run_file(status="complete")
            self.manifest.update()
            yield Progress("done", done, self.total, elapsed=time.perf_counter() - t_start,
                           message="nothing to do: every scene is complete")
            return

        yield Progress("setup", done, self.total, message="setting up Blender scene")
        t0 = time.perf_counter()
        world = _BlenderWorld(self.cfg, self.out)
        world.setup()
        write_models(self.out / layout.MODELS_DIR, world.model_meshes())
        self.stats["seconds"]["setup"] = time.perf_counter() - t0
        self.stats["imports"] = world.objects.import_count

        made = 0           # renders made in this call (for the ETA)
        t_loop = time.perf_counter()
        try:
            for i in todo:
                if self._cancel:
                    yield from self._cancelled(done, i, t_start)
                    return
                sdir = self.out / layout.scene_name(i)
                if sdir.exists():                   # a scene killed mid-way is made again from scratch
                    shutil.rmtree(sdir)
                sdir.mkdir(parents=True)
                yield Progress("scene", done, self.total, scene=i, message="dropping parts")
                scene, pose_indices, sim_seconds = world.start_scene(i, self.cfg.scene.seed, self.plan[i])
                for k, v in sim_seconds.items():
                    self.stats["seconds"][k] += v
                self.stats["frames"][scene["name"]] = scene["simulation"]["frames"]
                add_to_totals(self.stats["physics"], scene["simulation"])
                for r, pose_index in enumerate(pose_indices):
                    rec, secs = world.render(i, r, pose_index, sdir, self.cfg.scene.seed,
                                             image_id=int(self.first_image_id[i] + r))
                    scene["renders"].append(rec)
                    for k, v in secs.items():
                        self.stats["seconds"][k] += v
                    done += 1
                    made += 1
                    rate = (time.perf_counter() - t_loop) / made
                    if r == 0:
                        secs = {**sim_seconds, **secs}
                    warnings = self._quality_gate(i, r, world, scene, rec)
                    yield Progress("render", done, self.total, scene=i, render=r,
                                   elapsed=time.perf_counter() - t_start, eta=rate * (self.total - done),
                                   seconds=secs, message="rendered" + "".join(f" [warning: {w}]" for w in warnings))
                    if self._cancel:
                        break
                t0 = time.perf_counter()
                complete = len(scene["renders"]) == self.plan[i]
                scene["complete"] = complete
                if complete:
                    writers.add_scene(sdir, scene)
                else:
                    write_scene(sdir, scene)        # the record of a cancelled scene (not complete)
                world.finish_scene()
                self.stats["seconds"]["write"] += time.perf_counter() - t0
                self.manifest.update()
                if complete:
                    self._mark_scene_done(i)
                    yield Progress("scene_done", done, self.total, scene=i, elapsed=time.perf_counter() - t_start,
                                   message=physics_line({"parts": len(scene["objects"]), **scene["simulation"]}))
                if self._cancel:
                    yield from self._cancelled(done, i, t_start)
                    return
        finally:
            world.close()
        writers.finish()
        self._write_run_file(status="complete")
        self.manifest.update()
        yield Progress("done", done, self.total, elapsed=time.perf_counter() - t_start,
                       message=f"finished {made} render(s) in {_fmt_s(time.perf_counter() - t_start)}; "
                               f"{totals_line(self.stats['physics'])}")

    def _cancelled(self, done: int, scene: int, t_start: float) -> Iterator[Progress]:
        self._write_run_file(status="cancelled")
        self.manifest.update()
        yield Progress("cancelled", done, self.total, scene=scene, elapsed=time.perf_counter() - t_start,
                       message="cancelled: everything written so far is kept; --resume continues")

    # -- quality gates ----------------------------------------------------------------------------
    def _quality_gate(self, i: int, r: int, world, scene: dict, rec: dict) -> list[str]:
        """Warnings of one render (datapipe.quality), kept in run.json; with strict=True an error."""
        sl_info = rec.get("structured_light") or {}
        warnings = render_warnings(
            rgb=world.last_rgb, visible_px=[o["px_count_visib"] for o in rec["objects"]],
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
            "stats": self.stats,
        })
        rec.setdefault("scenes_done", [])
        write_json_atomic(self.out / layout.RUN_FILE, rec)

    def _mark_scene_done(self, i: int) -> None:
        rec = self._run_record()
        done = set(rec.get("scenes_done", []))
        done.add(layout.scene_name(i))
        rec["scenes_done"] = sorted(done)
        rec["stats"] = self.stats
        write_json_atomic(self.out / layout.RUN_FILE, rec)


def _files_present(sdir: Path, scene: dict) -> bool:
    """Every file the scene's renders list is on disk (a complete scene.json alone is not enough)."""
    try:
        return all((sdir / rel).is_file() for rd in scene["renders"] for rel in rd["files"].values())
    except (KeyError, TypeError, AttributeError):
        return False


class _BlenderWorld:
    """The bpy side of one run: built once, then scene after scene."""

    def __init__(self, cfg: Config, out: Path):
        self.cfg, self.out = cfg, out

    def setup(self) -> None:
        from .camera import BlendCamera
        from .objects import ObjectManager
        from .renderer import Renderer
        from .scene import BlendScene
        from .simulation import Simulation
        from .variety import SceneVariety

        self.blend = BlendScene(self.cfg)
        self.blend.setup()
        bscene = self.blend.scene
        self.camera = BlendCamera(self.cfg, bscene)
        self.camera.setup()
        self.variety = SceneVariety(self.cfg, self.blend, self.camera)
        self.objects = ObjectManager(self.cfg, self.blend)
        self.objects.load_sources()
        self.simulation = Simulation(self.cfg, self.blend)
        self.renderer = Renderer(self.cfg, bscene, self.camera)
        self.renderer.setup()
        self.sl = None
        if self.cfg.structured_light.enabled:
            from .structured_light import StructuredLightCamera
            self.sl = StructuredLightCamera(self.cfg, bscene, self.camera, self.renderer)
            self.sl.setup()

    def model_meshes(self) -> dict:
        """{obj_id: (verts m, faces, normals)} of every object entry (scale baked), for OUT/models."""
        return {i + 1: self.objects.model_mesh(i) for i in range(len(self.cfg.objects))}

    def start_scene(self, i: int, base: int, n_renders: int):
        from .simulation import drop_scene
        seed_python(base, i)
        rng = scene_rng(base, i)
        t0 = time.perf_counter()
        drawn = self.variety.apply_scene(base, i)      # bin and lights first: placement fits the bin
        t1 = time.perf_counter()
        # populate + simulate (again from a derived seed when too many parts were lost)
        sim, rng = drop_scene(self.objects, self.simulation, rng, scene_seed(base, i))
        t2 = time.perf_counter()
        pose_indices = self.variety.pose_plan(rng, n_renders)
        self.instances = sim.kept
        from . import materials        # on a random stream of their own: a list changes no pose
        labels = materials.apply_to_instances(self.cfg, sim.kept, scene_seed(base, i))
        self.materials = {inst.name: lab for inst, lab in zip(sim.kept, labels)}
        objects = [self._object_record(inst) for inst in sim.kept]
        scene = {
            "scene_id": i, "name": layout.scene_name(i), "seed": scene_seed(base, i),
            "simulation": sim.summary(),
            **drawn, "objects": objects, "renders": [],
        }
        return scene, pose_indices, {"placement": t1 - t0 + sim.placement_seconds,
                                     "simulation": t2 - t1 - sim.placement_seconds}

    def _object_record(self, inst) -> dict:
        return {"name": inst.name, "filename": inst.filename, "obj_id": inst.entry_index + 1,
                "mask_index": inst.mask_index, "material": self.materials.get(inst.name, "file")}

    def render(self, i: int, r: int, pose_index: int, sdir: Path, base: int, *, image_id: int):
        rdir = sdir / layout.render_name(r)
        rdir.mkdir(parents=True, exist_ok=True)
        T_world_cam, sampled = self.variety.place_camera(pose_index, base, i, r)
        T_world_blcam = np.array(self.camera.obj.matrix_world, dtype=np.float64)
        seed = render_seed(base, i, r)
        t0 = time.perf_counter()
        out = self.renderer.render(rdir, seed)
        t1 = time.perf_counter()
        self.last_rgb = out.rgb                 # for the quality gate, not kept
        rec = {
            "render_id": r, "name": layout.render_name(r), "image_id": image_id, "pose_index": pose_index,
            "K": self.camera.K, "resolution": list(self.camera.resolution),
            "T_world_cam": T_world_cam, "T_world_blcam": T_world_blcam, "seed": seed,
            "files": {k: str(Path(p).relative_to(sdir)) for k, p in out.files.items()},
            "objects": [],
        }
        if sampled is not None:
            rec["camera_sampler"] = sampled
        T_cam_world = np.linalg.inv(T_world_cam)
        T_blcam_world = np.linalg.inv(T_world_blcam)
        for inst in self.instances:
            T_world_obj = np.array(inst.obj.matrix_world, dtype=np.float64)
            o = self._object_record(inst)
            o["T_cam_obj"] = T_cam_world @ T_world_obj
            o["cam2obj_pose"] = T_blcam_world @ T_world_obj
            o["px_count_visib"] = int(np.count_nonzero(out.mask == inst.mask_index)) if out.mask is not None else None
            rec["objects"].append(o)
        cycles_s = float(getattr(out, "seconds", t1 - t0) or 0.0)
        secs = {"render": cycles_s, "write": max(0.0, (t1 - t0) - cycles_s)}   # EXR read-back + file writes
        if self.sl is not None:
            t2 = time.perf_counter()
            rec["structured_light"] = self.sl.process(rdir, seed, T_world_cam, sdir)
            rec["files"].update(rec["structured_light"].pop("files", {}))
            secs["structured_light"] = time.perf_counter() - t2
        return rec, secs

    def finish_scene(self) -> None:
        """Delete what the scene created (templates, camera, projector stay)."""
        self.objects.clear()

    def close(self) -> None:
        """Remove the projector lights, patterns and fringe layers (nothing left in the user's scene)."""
        sl_cam = getattr(self, "sl", None)
        if sl_cam is not None:
            sl_cam.teardown()
            self.sl = None
