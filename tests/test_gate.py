"""Issue 22: one gate of checks (datapipe/engine/gate.py). Its steps run in one order and stop at the
first that refuses; every entry that checks or starts a run goes through it, seen by behaviour: the
gate replaced by a recorder that refuses, each entry must stop with the gate's message and write
nothing. No bpy: the meshes step is recorded, not run (the real one: tests/blender/test_ui_gate.py).
"""
import json

import pytest

import fixtures_native as fx
from fake_world import BoxWorld
from datapipe import cli, config as C
from datapipe.engine import gate
from datapipe.engine.pipeline import Pipeline
from datapipe.core.world import BlenderWorld
from datapipe.engine.distributed import run_distributed
from datapipe.errors import ConfigError, DataPipeError, Problem

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)


@pytest.fixture
def cfg(tmp_path):
    c = fx.default_config(num_renders=2, min_per_scene=1, max_per_scene=1, resolution=(32, 24),
                          mesh_dir=tmp_path / "meshes")
    c.output.overview = False
    return c


@pytest.fixture
def steps(monkeypatch):
    """Each step of the gate records its name when it runs (the meshes step without Blender)."""
    seen = []

    def record(name, fn):
        def wrapped(*a, **kw):
            seen.append(name)
            return fn(*a, **kw)
        return wrapped
    monkeypatch.setattr(C.Config, "validate", record("config", C.Config.validate))
    monkeypatch.setattr(gate, "_mesh_preflight", record("meshes", lambda cfg, session, boxes=None: {}))
    monkeypatch.setattr(gate, "_part_fit", record("part_fit", gate._part_fit))
    monkeypatch.setattr(gate, "device_warnings", record("device", gate.device_warnings))
    monkeypatch.setattr(gate, "memory_warnings", record("memory", gate.memory_warnings))
    return seen


def test_the_steps_run_in_order(cfg, steps, tmp_path):
    report = gate.run_checks(cfg, folder=lambda c: steps.append("folder"))
    assert steps == list(gate.STEPS) == report.steps
    assert report.steps == ["config", "folder", "meshes", "part_fit", "device", "memory"]
    steps.clear()
    assert gate.run_checks(cfg, blender=False).steps == steps == ["config", "part_fit", "device", "memory"]
    steps.clear()
    assert gate.run_checks(cfg, inputs=False, folder=lambda c: steps.append("folder")).steps == ["config", "folder"]


def test_a_refusing_step_stops_the_gate(cfg, steps, monkeypatch):
    folder = []

    def used_folder(c):
        steps.append("folder")
        raise DataPipeError("out: not empty")
    with pytest.raises(DataPipeError, match="not empty"):      # refused before Blender would start
        gate.run_checks(cfg, folder=used_folder)
    assert steps == ["config", "folder"]
    steps.clear()

    def broken_mesh(cfg, session, boxes=None):
        steps.append("meshes")
        raise ConfigError(Problem("objects[0].filepath", "broken", "fix it"))
    monkeypatch.setattr(gate, "_mesh_preflight", broken_mesh)
    with pytest.raises(ConfigError, match=r"objects\[0\]\.filepath: broken"):
        gate.run_checks(cfg, folder=folder.append)
    assert steps == ["config", "meshes"] and len(folder) == 1
    steps.clear()
    bad = cfg.copy()
    bad.scene.num_renders = 0
    with pytest.raises(ConfigError, match="scene.num_renders"):
        gate.run_checks(bad, folder=folder.append)
    assert steps == ["config"] and len(folder) == 1     # the field rules stop it before the folder


def test_the_fill_refusal_comes_from_the_measured_volumes(cfg, monkeypatch):
    """The part-fit step refuses when the hull volumes the meshes step measured cannot fit the bin."""
    monkeypatch.setattr(gate, "_mesh_preflight", lambda c, session, boxes=None: {0: 1.0})     # a 1 m^3 part
    with pytest.raises(ConfigError, match=r"objects\[0\]\.max_instances: a scene may hold"):
        gate.run_checks(cfg)


def test_memory_warning_against_this_machine(cfg, monkeypatch):
    cfg.structured_light.enabled = True
    need = C.fringe_memory_bytes(cfg)
    monkeypatch.setattr(gate, "machine_memory_bytes", lambda: need // 2)
    (w,) = gate.memory_warnings(cfg)
    assert w.startswith("structured_light: one render's fringe work needs about") and "(fix: " in w
    monkeypatch.setattr(gate, "machine_memory_bytes", lambda: need)
    assert gate.memory_warnings(cfg) == []
    cfg.structured_light.enabled = False
    monkeypatch.setattr(gate, "machine_memory_bytes", lambda: 1)
    assert gate.memory_warnings(cfg) == []
    assert gate.machine_memory_bytes() is None or gate.machine_memory_bytes() > 0


def test_the_device_full_resolution_fringe_stack_fits_and_validate_says_so(monkeypatch):
    """The dense bin preset on the Zivid 2+ M60 at its full 2448 x 2048 (binning 1): one render's fringe
    work, counted by hand from what it holds, is ~2.4 GiB, inside a 24 GiB machine, and validate's
    summary says the figure and the machine's memory before any work."""
    d = json.loads((C.presets_dir() / "bin_picking.json").read_text())
    d["binning"] = 1
    cfg = C.Config.from_dict(d)
    assert list(cfg.camera.resolution) == [2448, 2048]
    s, (Wp, Hp), (W, H) = cfg.structured_light, cfg.projector.resolution, cfg.camera.resolution
    frames = len(s.periods) * s.steps + (s.steps if s.reflection_filter in ("auto", "global") else 0)
    per_frame = Wp * Hp * 4 * 4 + (2 * W) * (2 * H) * 4 + W * H * 4 + (8 * W * H if s.hdr else 0)
    need = C.fringe_memory_bytes(cfg)
    assert need == frames * per_frame            # pattern RGBA float + 2x2 supersampled float32 + mean (+HDR)
    assert need < 24 * 2**30 and need < 3 * 2**30
    monkeypatch.setattr(gate, "machine_memory_bytes", lambda: 24 * 2**30)
    assert gate.memory_warnings(cfg) == []
    assert gate.memory_summary(cfg) == f"fringe work about {need / 2**30:.1f} GiB per render (this machine 24.0 GiB)"
    monkeypatch.setattr(gate, "machine_memory_bytes", lambda: need - 1)     # a smaller machine: warned
    assert len(gate.memory_warnings(cfg)) == 1


# ------------------------------------------------------------------------------------------------
# every entry calls the gate (and nothing runs past its refusal)

class Refused(DataPipeError):
    pass


@pytest.fixture
def calls(monkeypatch):
    """The gate replaced by a recorder that refuses with a message of its own."""
    seen = []

    def refuse(cfg, **kw):
        seen.append(kw)
        raise Refused("gate: refused (fix: nothing)")
    monkeypatch.setattr(gate, "run_checks", refuse)
    return seen


def test_pipeline_checks_and_runs_through_the_gate(cfg, calls, tmp_path):
    out = tmp_path / "out"
    for call in (lambda p: p.check(), lambda p: list(p.run())):
        with pytest.raises(Refused):
            call(Pipeline(cfg, out, world=BoxWorld.factory()))
    assert [c["blender"] for c in calls] == [False, False]          # a fake world imports no meshes
    assert all(c["folder"] is not None for c in calls)
    with pytest.raises(Refused):
        Pipeline(cfg, out).check()
    assert calls[-1]["blender"] is True and BlenderWorld.imports_meshes   # the Blender world: the mesh preflight
    assert not out.exists()


@pytest.mark.parametrize("argv", [["validate", "{p}"], ["run", "{p}", "--out", "{o}"],
                                  ["run", "{p}", "--out", "{o}", "--ray"]])
def test_the_cli_checks_through_the_gate(cfg, calls, tmp_path, capsys, argv):
    p = tmp_path / "p.json"
    C.save(cfg, p)
    out = tmp_path / "o"
    assert cli.main([a.format(p=p, o=out) for a in argv]) == 2
    assert capsys.readouterr().err == "datapipe: error: gate: refused (fix: nothing)\n"
    (call,) = calls
    assert call.get("blender", True) is True and call.get("blender_session") is not None
    assert (call.get("folder") is None) == (argv[0] == "validate")     # validate has no output folder
    assert not out.exists()


def test_the_ray_driver_checks_through_the_gate(cfg, calls, tmp_path):
    p = tmp_path / "p.json"
    C.save(cfg, p)
    with pytest.raises(Refused):
        run_distributed(p, tmp_path / "o", runner=["false"])
    (call,) = calls
    assert call["blender"] is True and call["folder"] is not None
    assert not (tmp_path / "o").exists()


def test_with_scene_fill_the_bin_bound_is_the_share_plus_one_part(cfg, monkeypatch):
    """scene.fill stops at its share (datapipe/draws/fill.py): max_instances far past the bin are then only a
    cap, as in tests/blender/test_dense_progress.py; the min_instances and a part too large for the
    share's room are still refused."""
    from datapipe.checks.part_fit import RANDOM_PACKING_MAX, bin_volume, fill_problems
    cfg.scene.fill = [0.15, 0.15]
    room = RANDOM_PACKING_MAX * bin_volume(cfg.scene)
    part = room / 100                                   # 300 of them would be 3 x the room
    for o in cfg.objects:
        o.min_instances, o.max_instances = 0, 100
    volumes = {i: part for i in range(len(cfg.objects))}
    assert fill_problems(cfg, volumes) == []
    cfg.scene.fill = None
    assert [p.path for p in fill_problems(cfg, volumes)] == ["objects[0].max_instances"]
    cfg.scene.fill = [0.15, 0.15]
    for o in cfg.objects:
        o.min_instances = 40                            # 120 parts to start with: 1.2 x the room
    assert [p.path for p in fill_problems(cfg, volumes)] == ["objects[0].min_instances"]
    for o in cfg.objects:
        o.min_instances = 0
    big = (RANDOM_PACKING_MAX - 0.15) * bin_volume(cfg.scene) * 1.01      # the share plus this one: too much
    assert [p.path for p in fill_problems(cfg, {0: big, 1: part, 2: part})] == ["scene.fill"]
    assert fill_problems(cfg, {0: big * 0.98, 1: part, 2: part}) == []
