"""CLI refusals that must happen before any Blender work (these run without bpy work)."""
import json
import subprocess
import sys

from datapipe import config as C


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "datapipe", *args], capture_output=True, text=True, cwd=cwd)


def test_validate_ok_and_bad(tmp_path):
    r = _run("validate", str(C.presets_dir() / "default.json"))
    assert r.returncode == 0 and "OK" in r.stdout
    # what the structured-light camera will do: "auto" resolved from the materials, the images
    shiny = C.load(C.presets_dir() / "default.json")
    shiny.structured_light.enabled = True
    shiny.objects[0].material = "steel"
    shiny.camera.sampler.kind = "bin_view"
    C.save(shiny, tmp_path / "shiny.json")
    r = _run("validate", str(tmp_path / "shiny.json"))
    assert r.returncode == 0, r.stderr
    assert "fringe mode quadrature (auto: a configured material is shiny;" in r.stdout
    assert "12 fringe images (+4 row code on shiny renders), mixed from 7 rendered images" in r.stdout
    assert "one per Cycles layer (a material has a colour or comes from its mesh file" in r.stdout
    for entry in shiny.objects:                          # every material grey: three images per layer
        entry.material = ["steel", "matte_plastic"]
    C.save(shiny, tmp_path / "grey.json")
    r = _run("validate", str(tmp_path / "grey.json"))
    assert "three per Cycles layer: 4 layers (every material is grey)" in r.stdout, r.stdout
    shiny.structured_light.projector_gamma = 2.2         # not a mix of cos and sin: every pattern path-traced
    C.save(shiny, tmp_path / "gamma.json")
    r = _run("validate", str(tmp_path / "gamma.json"))
    assert r.returncode == 0, r.stderr
    assert "fringe mode render (auto: a configured material is shiny, and projector_gamma 2.2" in r.stdout
    assert "bin_view sampler" in r.stdout and "camera poses," not in r.stdout
    bad = C.Config().to_dict()
    bad["scene"]["num_renders"] = 0
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    r = _run("validate", str(tmp_path / "bad.json"))
    assert r.returncode == 2
    assert "scene.num_renders" in r.stderr and "objects: no objects" in r.stderr
    assert "Traceback" not in r.stderr


def test_bad_preset_run_writes_nothing(tmp_path):
    bad = C.default_config()
    bad.objects[0].filepath = str(tmp_path / "missing.obj")
    C.save(bad, tmp_path / "bad.json")
    out = tmp_path / "out"
    r = _run("run", str(tmp_path / "bad.json"), "--out", str(out))
    assert r.returncode == 2 and "objects[0].filepath" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


def test_non_empty_output_refused_without_resume(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    r = _run("run", str(C.presets_dir() / "default.json"), "--out", str(out))
    assert r.returncode == 2 and "not empty" in r.stderr and "--resume" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["precious.txt"]
    r = _run("run", str(C.presets_dir() / "default.json"), "--out", str(out), "--resume")
    assert r.returncode == 2 and "cannot resume" in r.stderr
    r = _run("run", str(C.presets_dir() / "default.json"), "--out", str(out), "--force")
    assert r.returncode == 2 and "refusing to empty" in r.stderr
    assert (out / "precious.txt").read_text() == "keep me"


def test_bad_shard_argument(tmp_path):
    r = _run("run", str(C.presets_dir() / "default.json"), "--out", str(tmp_path / "o"), "--shard", "3/2")
    assert r.returncode == 2 and "shard" in r.stderr
