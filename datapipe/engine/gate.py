"""The one gate of checks before a run: `run_checks(cfg, ...)`. No bpy at import.

Every way to start or check a run goes through it and through nothing else: `Pipeline.check`
(so the add-on's Check and Run operators and any Python caller), `datapipe validate` and
`datapipe run` (through `Pipeline.check`), and the Ray driver (`distributed.run_distributed`). So
a run started from the sidebar refuses what `datapipe run` refuses, with the same message.

The steps, in order (STEPS); a step that finds errors stops the gate with every problem it found:
  config   the field rules (`Config.validate`: types, ranges, files present, the fringe stack's fixed
           memory limit), then BOP models folders expanded to one entry per object
  folder   the output folder's refusals, given by the caller (`Pipeline` or the Ray driver): cheap,
           so a used folder is refused in a second, before Blender starts; and changing, so also
           re-run alone under the run's lock (`inputs=False`)
  meshes   (with Blender) each mesh file imported and measured, `scene.blend_file` read by Blender
           (core/preflight.py, imported here only when asked: it needs bpy)
           and, with BOP output, a warning per mesh whose origin is far from its bounding box's
           centre while objects[i].origin is "file" (checks/origins.py)
  part_fit the parts' convex hulls against the bin (an error: part_fit.fill_problems, from the hull
           volumes the meshes step measured) and each part against the drop zone (a warning)
  device   the bin against a real device's working distance and field of view (warnings)
  memory   one render's fringe work against this machine's memory (a warning: a preset is often
           checked on one machine and run on another)
"""
from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, ContextManager

from ..config import Config, fringe_memory_bytes
from ..checks.device_checks import device_warnings
from ..io.bop_sensor import sensor_warnings
from ..checks.origins import origin_warnings
from ..errors import ConfigError
from ..io.bop_models import expand_bop_objects
from ..checks.part_fit import fill_problems, part_fit_warnings

STEPS = ("config", "folder", "meshes", "part_fit", "device", "memory")


@dataclass
class CheckReport:
    """What passed the gate: the config a run makes (validated, BOP folders expanded), the warnings
    (one line each, as `datapipe validate` prints them after "datapipe: warning: ") and the steps
    that ran, in order."""
    cfg: Config
    warnings: list[str] = field(default_factory=list)
    steps: list[str] = field(default_factory=list)


def run_checks(cfg: Config, *, blender: bool = True, folder: Callable[[Config], None] | None = None,
               blender_session: Callable[[], ContextManager] | None = None, inputs: bool = True) -> CheckReport:
    """Every check before a run, in the order of STEPS; raises ConfigError (every problem of the
    failing step, each naming its field and the fix) or the folder step's DataPipeError.

    blender: run the meshes step (False where no Blender renders the parts: a fake world in tests,
    a Ray driver without bpy whose shards check them). folder: the output folder's check, given the
    checked config; None: no folder (`datapipe validate`). blender_session: makes the context the
    meshes step runs in, entered before bpy is first imported (the CLI's: Blender's output to its
    log, the bpy module's empty scene; the add-on needs none). inputs=False: only the config rules
    and the folder (again under the run's lock, after a full pass)."""
    report = CheckReport(cfg)
    cfg.validate()
    report.steps.append("config")
    checked = expand_bop_objects(cfg)          # one entry per object of a BOP models folder
    report.cfg = checked
    if folder is not None:                     # cheap: a used folder is refused before Blender starts
        folder(checked)
        report.steps.append("folder")
    if inputs:
        volumes = None
        if blender:
            boxes: dict[int, tuple] = {}
            volumes = _mesh_preflight(checked, blender_session, boxes)
            report.warnings += origin_warnings(checked, boxes)
            report.steps.append("meshes")
        report.warnings += _part_fit(cfg, checked, volumes)
        report.steps.append("part_fit")
        report.warnings += device_warnings(cfg)
        report.warnings += sensor_warnings(cfg)
        report.steps.append("device")
        report.warnings += memory_warnings(checked)
        report.steps.append("memory")
    return report


def _mesh_preflight(cfg: Config, session: Callable[[], ContextManager] | None,
                    boxes: dict[int, tuple] | None = None) -> dict[int, float] | None:
    """The Blender checks; returns the hull volumes (None with scene.blend_file: its bin is unknown);
    fills `boxes` with the meshes' bounding boxes."""
    with session() if session is not None else contextlib.nullcontext():
        from ..core.preflight import check_blend, measure_meshes     # bpy: only here
        problems = check_blend(cfg)
        mesh_problems, volumes = measure_meshes(cfg, boxes)
    problems += mesh_problems
    if problems:
        raise ConfigError(problems)
    return None if cfg.scene.blend_file else volumes


def _part_fit(cfg: Config, checked: Config, volumes: dict[int, float] | None) -> list[str]:
    """The fill refusal (needs the measured volumes) and the drop-zone warnings. The warnings read the
    preset as written (`cfg`: its objects[i] are the user's entries)."""
    if volumes is not None:
        problems = fill_problems(checked, volumes)
        if problems:
            raise ConfigError(problems)
    return part_fit_warnings(cfg)


def memory_warnings(cfg: Config) -> list[str]:
    """A line when one render's fringe work (config.fringe_memory_bytes) needs more memory than this
    machine (or its container) has: the run would be killed, or swap for hours, at its first
    structured-light render. Blender's scene needs memory besides, so this is a floor, not a forecast."""
    if not cfg.structured_light.enabled:
        return []
    have = machine_memory_bytes()
    need = fringe_memory_bytes(cfg)
    if have is None or need <= have:
        return []
    return [f"structured_light: one render's fringe work needs about {need / 2**30:.1f} GiB and this machine has "
            f"{have / 2**30:.1f} GiB of memory: the run is likely killed at its first structured-light render "
            "(fix: run it on a larger machine, or use fewer structured_light.steps or periods, or a smaller "
            "camera or projector resolution)"]


def memory_summary(cfg: Config) -> str:
    """What `validate` says of one render's fringe work, fitting or not: "fringe work about 2.4 GiB
    per render (this machine 22.9 GiB)"."""
    have = machine_memory_bytes()
    text = f"fringe work about {fringe_memory_bytes(cfg) / 2**30:.1f} GiB per render"
    return text + (f" (this machine {have / 2**30:.1f} GiB)" if have is not None else "")


def machine_memory_bytes() -> int | None:
    """Physical memory, or the container's limit (cgroup v2 memory.max) when lower; None where unknown."""
    try:
        have = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):     # Windows: no sysconf
        return None
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
    except OSError:
        return have
    return min(have, int(limit)) if limit.isdigit() else have
