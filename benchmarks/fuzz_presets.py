"""Generated hostile presets through load + validate + the Blender preflight: every answer must be a
valid Config or one of DataPipe's own errors naming the field and the fix.

    .venv/bin/python benchmarks/fuzz_presets.py [--n 3000] [--seed 21] [--preflight-share 1.0] [--cli 80]

Each preset starts from the demo preset (JSON, relative mesh paths) or the original add-on's input
dict (pickle, any protocol), gets 1-4 mutations and is written to a file in a folder that also holds
the demo meshes, broken meshes, symlink loops and .blend files (a real one, one with a Blender header
and random bytes, one that is text). Mutations: a field set to a hostile value (NUL bytes and lone
surrogates in paths and names, names past 63 bytes, 401-digit ints, 1e308, NaN, lists nested up to
1,200 deep, periods of a million or 2**62, part counts past the bin's volume), a random position
replaced, a key removed or added, a list grown; a few files are cut short or have bytes flipped, and
a few pickles hold a dict key nested up to 200,000 tuples deep. Object entries also get BOP models
folders (`bop_models`) whose models_info.json is good, a number or null entry, 200,000 levels deep, a
list, cut short, a FIFO, missing, with a bad key, garbage or NaN symmetries, or whose PLY is a FIFO;
and glTF / .glb files whose buffers or images are /dev/zero (byteLength 1e9), a FIFO, missing, shorter
than their byteLength, or good (a data URI, a file beside it), or whose own JSON is a FIFO or 200,000
levels deep, and OBJ files whose .mtl or a texture it names is a FIFO (issue 33: these hung
`validate`, exhausted its memory or ended in a traceback). Then, in process and in this order:
`config.load` (the CLI's loader), `Config.validate()` (files checked), and for the given share of
the presets validate accepts, the gate `engine.gate.run_checks` without an output folder (as `validate`:
mesh imports, the .blend read by Blender, the bin volume) on the bpy module. `--cli N` then runs N of them (a quarter accepted, the rest
refused, evenly by the stage that refused them) through `python -m datapipe validate` and
`run --out` in subprocesses: exit codes, a fix in the message, nothing written, no traceback.
Each preset runs under a watchdog (HANG_S): one that has not answered by then is counted as a hang.

Writes benchmarks/results/fuzz_presets.md (with fuzz_presets_notes.md appended). A foreign exception
(anything but ConfigError / DataPipeError, or one of those without a field path and a fix) is listed
by kind with an example, and its preset kept in the folder printed at the end.
"""
from __future__ import annotations

import collections
import copy
import json
import math
import os
import pickle
import random
import shutil
import signal
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from harness import RESULTS, ROOT, Stopwatch, on_path, parser, write_with_notes

on_path()
from datapipe import config as C  # noqa: E402
from datapipe.errors import ConfigError, DataPipeError  # noqa: E402

HOSTILE_TEXT = ["", "\x00", "a\x00.obj", "\x00.blend", "\ud800", "\ud800.obj", "\udc80.obj", "peg\n", "\t",
                "é" * 40, "x" * 70, "../" * 40 + "etc/passwd", "/", ".", "CON", "steel", "pool", "bin_view",
                "{frame}", "peg.obj", "datapipe_template_peg"]
HUGE = [10**400, int("9" * 401), 2**62 + 1, 2**62 - 1, 2**63, -2**63 - 1, 1e308, -1e308, math.inf, -math.inf,
        math.nan, -0.0, 1e-300, 0, -1, 1000003, 999983]
PERIOD_SETS = [[1000003, 999983], [2**62 + 1, 2**62 - 1], [1, 8, 64], [70, 64, 59], [13, 7], [8, 8], [1, 304],
               [1, 305], [1, 8, 3000], [2.5, 1], [], [0], [1, 2, 3, 4, 5, 6, 7, 8, 9]]


HANG_S = 60          # a preset's load + validate + preflight takes well under a second; 60 s is a hang


class Hang(Exception):
    """Raised by the watchdog's SIGALRM in a preset that has not answered within HANG_S."""


def nested(depth: int, leaf="steel"):
    for _ in range(depth):
        leaf = [leaf]
    return leaf


def hostile_value(rng: random.Random):
    kind = rng.randrange(9)
    if kind == 0:
        return rng.choice(HOSTILE_TEXT)
    if kind == 1:
        return rng.choice(HUGE)
    if kind == 2:
        return nested(rng.choice([2, 9, 50, 950, 1200]))
    if kind == 3:
        return rng.choice(PERIOD_SETS)
    if kind == 4:
        return {rng.choice(["roughness", "ior", "metallic", "name", "base_color", "x"]): hostile_value(rng)}
    if kind == 5:
        return [hostile_value(rng) for _ in range(rng.randrange(4))]
    if kind == 6:
        return rng.choice([None, True, False, "", [], {}])
    if kind == 7:
        return rng.uniform(-10, 10) * 10 ** rng.randrange(-6, 6)
    return rng.randrange(-3, 600)


def file_paths(files: dict) -> list[str]:
    """Every file a mesh or blend field can name (the glTF files among them; not the BOP folders)."""
    return [v for v in files.values() if isinstance(v, str)] + files["gltf"]


def targeted(rng: random.Random, d: dict, files: dict) -> None:
    """Set one of the fields where a hostile value reaches the OS, Blender or the decoder."""
    objs = d.get("objects")
    if isinstance(objs, dict):                                   # the legacy layout
        lst = objs.get("objects_list")
        entries = [e for e in lst if isinstance(e, dict)] if isinstance(lst, list) else []
        if entries:
            rng.choice(entries)[rng.choice(["filepath", "scale", "max", "min"])] = rng.choice(
                [rng.choice(HOSTILE_TEXT) + ".obj", rng.choice(file_paths(files)), hostile_value(rng)])
        return
    choice = rng.randrange(10)
    entries = [e for e in objs if isinstance(e, dict)] if isinstance(objs, list) else []
    o = rng.choice(entries) if entries else None
    if choice == 8 and o is not None:                              # a BOP models folder (good or hostile)
        o.pop("filepath", None)
        o["bop_models"] = rng.choice(files["bop"] + ["bop_ok"] * 4)     # the good folder a quarter of the time
        o["bop_obj_ids"] = rng.choice([[], [], [1], [1, 2], [7]])
        o["symmetries"] = rng.choice(["auto", "auto", "none", "detect"])
    elif choice == 9 and o is not None:                            # a glTF with hostile buffers/images
        o["filepath"] = rng.choice(files["gltf"])
    elif choice == 0 and o is not None:
        o["filepath"] = rng.choice([rng.choice(HOSTILE_TEXT) + ".obj", rng.choice(file_paths(files))])
    elif choice == 1 and o is not None:
        o["name"] = rng.choice(HOSTILE_TEXT + ["é" * rng.randrange(25, 35), "n" * rng.randrange(55, 65)])
    elif choice == 2 and o is not None:
        o["material"] = hostile_value(rng) if rng.random() < 0.7 else rng.choice(["steel", "painted", "file"])
    elif choice == 3 and o is not None:                            # counts near and past the bin's volume
        o["min_instances"], o["max_instances"] = 1, rng.choice([1, 50, 150, 300, 500])
        o["scale"] = rng.choice([1.0, 1.0, 2.0, 3.0, 1e-6, 1e3])
    elif choice == 4 and isinstance(d.get("scene"), dict):
        d["scene"]["blend_file"] = rng.choice([files["blend_ok"], files["blend_garbage"], files["blend_text"],
                                               files["blend_loop"],
                                               rng.choice(HOSTILE_TEXT) + ".blend", None])
    elif choice == 5 and isinstance(d.get("scene"), dict):
        d["scene"]["bin_material"] = hostile_value(rng)
    elif choice == 6 and isinstance(d.get("structured_light"), dict):
        d["structured_light"]["enabled"] = True
        d["structured_light"]["periods"] = rng.choice(PERIOD_SETS)
    elif isinstance(d.get("output"), dict):
        d["output"]["path"] = rng.choice(HOSTILE_TEXT)


def positions(obj, prefix=(), depth=0):
    """Key paths of a preset, containers included (not below 6 levels)."""
    yield prefix
    if depth >= 6:
        return
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for k, v in items:
        yield from positions(v, prefix + (k,), depth + 1)


def mutate(rng: random.Random, base: dict, files: dict) -> dict:
    d = copy.deepcopy(base)
    for _ in range(rng.randint(1, 4)):
        op = rng.random()
        if op < 0.45:
            targeted(rng, d, files)
            continue
        path = rng.choice(list(positions(d)))
        parent = d
        for k in path[:-1]:
            parent = parent[k]
        if not path:
            if rng.random() < 0.05:
                d = hostile_value(rng)
                break
            continue
        target = parent[path[-1]]
        if op < 0.8:
            parent[path[-1]] = hostile_value(rng)
        elif op < 0.88 and isinstance(parent, dict):
            del parent[path[-1]]
        elif op < 0.94 and isinstance(target, dict):
            target[rng.choice(["x", "\ud800", "", "name", "periods"])] = hostile_value(rng)
        elif isinstance(target, list):
            target.extend(hostile_value(rng) for _ in range(rng.randint(1, 3)))
    return d


def encode(rng: random.Random, d, as_pickle: bool) -> bytes | None:
    try:
        raw = pickle.dumps(d, protocol=rng.randrange(6)) if as_pickle else json.dumps(d).encode()
    except (RecursionError, ValueError, OverflowError):
        return None                       # json/pickle cannot write it: no user can have such a file
    r = rng.random()
    if as_pickle and r < 0.02:            # a dict key nested deep, as opcodes (pickle.dumps refuses it):
        depth = rng.choice([3, 40, 2000, 200_000])              # hashing it crashed CPython in C
        return b"\x80\x02}K\x01" + b"\x85" * depth + b"K\x02s."
    if r < 0.03:
        raw = raw[:rng.randrange(len(raw) + 1)]
    elif r < 0.06 and raw:
        b = bytearray(raw)
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        raw = bytes(b)
    return raw


def make_files(folder: Path) -> dict:
    """The demo meshes, broken meshes and .blend files next to the presets (relative paths)."""
    import bpy
    for a in C.assets_dir().iterdir():
        shutil.copy(a, folder / a.name)
    (folder / "empty.obj").write_text("")
    (folder / "no_faces.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    (folder / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "flat.obj").write_text("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nf 1 2 3\n")
    (folder / "garbage.blend").write_bytes(b"BLENDER-v300" + random.Random(0).randbytes(4096))
    (folder / "text.blend").write_text("not a blend file")
    os.symlink("loop.obj", folder / "loop.obj")
    os.symlink("loop.blend", folder / "loop.blend")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "ok.blend"), copy=True)
    return {"peg": "peg.obj", "nut": "nut.obj", "bracket": "bracket.obj", "empty": "empty.obj",
            "no_faces": "no_faces.obj", "nan": "nan.obj", "flat": "flat.obj", "blend_ok": "ok.blend",
            "blend_garbage": "garbage.blend", "blend_text": "text.blend", "missing": "missing.obj",
            "loop": "loop.obj", "blend_loop": "loop.blend",
            "bop": make_bop_folders(folder), "gltf": make_gltf_files(folder)}


DEEP_JSON = "[" * 200_000 + "]" * 200_000


def make_bop_folders(folder: Path) -> list[str]:
    """BOP models folders (relative paths), one per models_info.json case: a good one and hostile ones."""
    import numpy as np
    from datapipe.io.models import model_info, write_ply
    V = np.array([[0, 0, 0], [40, 0, 0], [0, 30, 0], [0, 0, 20]], float)       # mm: a 40 mm tetrahedron
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    good = {**model_info(V), "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]}
    cases = {"ok": {"1": good, "2": dict(good)}, "number": {"1": 5}, "null": {"1": None}, "list": [1, 2],
             "bad_key": {"x": good}, "sym_garbage": {"1": {**good, "symmetries_discrete": "garbage"}},
             "sym_nan": {"1": {**good, "symmetries_continuous": [{"axis": [math.nan, 0, 1], "offset": [0, 0, 0]}]}},
             "diameter_text": {"1": {**good, "diameter": "big"}}}
    names = []
    for name in [*cases, "deep", "cut", "fifo_info", "fifo_ply", "no_info"]:
        d = folder / f"bop_{name}"
        d.mkdir()
        for k in (1, 2):
            if not (name == "fifo_ply" and k == 1):
                write_ply(d / f"obj_{k:06d}.ply", V, F)
        info = d / "models_info.json"
        if name == "fifo_ply":
            os.mkfifo(d / "obj_000001.ply")
            info.write_text(json.dumps(cases["ok"]))
        elif name == "deep":
            info.write_text('{"1": ' + DEEP_JSON + "}")
        elif name == "cut":
            info.write_text(json.dumps(cases["ok"])[:30])
        elif name == "fifo_info":
            os.mkfifo(info)
        elif name != "no_info":
            info.write_text(json.dumps(cases[name]))
        names.append(d.name)
    return names


def make_gltf_files(folder: Path) -> list[str]:
    """glTF / .glb files (relative paths) with good and hostile buffers and images, and OBJ files whose
    material library, or a texture it names, is a FIFO (or good, or missing)."""
    import base64
    import struct
    tri = struct.pack("<9f", 0, 0, 0, 0.03, 0, 0, 0, 0.03, 0.01)     # one triangle, m
    def doc(uri, n=len(tri), images=()):
        return {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "scene": 0, "nodes": [{"mesh": 0}],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
                "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                               "min": [0, 0, 0], "max": [0.03, 0.03, 0.01]}],
                "bufferViews": [{"buffer": 0, "byteLength": len(tri)}], "buffers": [{"uri": uri, "byteLength": n}],
                **({"images": [{"uri": u} for u in images]} if images else {})}
    (folder / "tri.bin").write_bytes(tri)
    (folder / "short.bin").write_bytes(tri[:8])
    os.mkfifo(folder / "fifo.bin")
    os.mkfifo(folder / "fifo.png")
    os.mkfifo(folder / "fifo_itself.gltf")
    cases = {"ok_data": doc("data:application/octet-stream;base64," + base64.b64encode(tri).decode()),
             "ok_file": doc("tri.bin"), "dev_zero": doc("/dev/zero", 10**9), "fifo": doc("fifo.bin"),
             "short": doc("short.bin"), "missing": doc("gone.bin"), "image_fifo": doc("tri.bin", images=["fifo.png"]),
             "length_text": doc("tri.bin", "36")}
    names = []
    for name, d in cases.items():
        (folder / f"{name}.gltf").write_text(json.dumps(d))
        names.append(f"{name}.gltf")
    (folder / "deep.gltf").write_text(DEEP_JSON)
    chunk = json.dumps(doc("fifo.bin")).encode()
    chunk += b" " * (-len(chunk) % 4)
    (folder / "fifo_buffer.glb").write_bytes(b"glTF" + struct.pack("<III", 2, 20 + len(chunk), len(chunk))
                                             + b"JSON" + chunk)
    obj = "v 0 0 0\nv 0.03 0 0\nv 0 0.03 0\nv 0 0 0.02\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"   # OBJ + .mtl
    os.mkfifo(folder / "fifo.mtl")
    (folder / "tex_fifo.mtl").write_text("newmtl a\nmap_Kd -s 1 1 1 fifo.png\n")
    (folder / "ok.mtl").write_text("newmtl a\nKd 0.5 0.5 0.5\n")
    for name, lib in (("mtl_fifo", "fifo.mtl"), ("mtl_tex_fifo", "tex_fifo.mtl"), ("mtl_ok", "ok.mtl"),
                      ("mtl_missing", "gone.mtl")):
        (folder / f"{name}.obj").write_text(f"mtllib {lib}\nusemtl a\n" + obj)
    return names + ["deep.gltf", "fifo_buffer.glb", "fifo_itself.gltf", "mtl_fifo.obj", "mtl_tex_fifo.obj",
                    "mtl_ok.obj", "mtl_missing.obj"]


def well_formed(e: Exception) -> bool:
    if isinstance(e, ConfigError):
        return bool(e.problems) and all(p.path and p.message and p.fix and str(p).count("(fix:") == 1
                                        for p in e.problems)
    return "(fix:" in str(e)


@dataclass
class Tally:
    """What the presets came to: outcome counts, the stage and field of each refusal, the foreign
    exceptions and hangs, the files per outcome (for the CLI check) and the CPU seconds."""
    work: Path
    counts: collections.Counter = field(default_factory=collections.Counter)
    stages: collections.Counter = field(default_factory=collections.Counter)
    fields: collections.Counter = field(default_factory=collections.Counter)
    preflight_fields: collections.Counter = field(default_factory=collections.Counter)   # only the preflight finds
    preflight_examples: dict = field(default_factory=dict)
    foreign: list = field(default_factory=list)
    outcomes: dict = field(default_factory=lambda: collections.defaultdict(list))  # stage refused at -> files
    cpu: collections.Counter = field(default_factory=collections.Counter)
    input_kinds: dict = field(default_factory=lambda: collections.defaultdict(collections.Counter))

    def refused(self, e: Exception, stage: str, path: Path, kinds: list[str]) -> None:
        if not well_formed(e):
            self.counts["project error without path or fix"] += 1
            self.foreign.append((path.name, f"{stage}: {type(e).__name__} without a path or fix", str(e)[:160]))
            return
        self.counts["clear error"] += 1
        self.stages[stage] += 1
        for k in kinds:
            self.input_kinds[k][f"refused ({stage})"] += 1
        for p in getattr(e, "problems", [])[:1]:
            name = p.path.split("[")[0].split(".")[0] + ("." + p.path.split(".")[-1].split("[")[0]
                                                         if "." in p.path else "")
            self.fields[name] += 1
            if stage == "preflight":
                self.preflight_fields[name] += 1
                self.preflight_examples.setdefault(name, p.message.replace(str(self.work), "DIR")[:110])
        if {q.path for q in getattr(e, "problems", [])} == {"output.path"}:
            stage = "output.path only"     # `run --out DIR` replaces that field: the CLI check skips it
        self.outcomes[stage].append(path)

    def failed(self, what: str, stage: str, path: Path, kinds: list[str], where: str, msg: str) -> None:
        """A hang or a foreign exception: a defect, kept with the preset's name."""
        self.counts[what] += 1
        for k in kinds:
            self.input_kinds[k][what] += 1
        self.foreign.append((path.name, f"{stage}: {where}", msg))


def judge(path: Path, kinds: list[str], rng, share: float, tally: Tally, run_checks) -> None:
    """One preset through load, validate and (for `share` of those validate accepts) the preflight,
    under the watchdog; the outcome goes into `tally`."""
    stage = "load"
    signal.alarm(HANG_S)                   # the watchdog: a preset that hangs is counted, not waited on
    try:
        t = time.process_time()
        cfg = C.load(path)
        stage = "validate"
        cfg.validate()
        tally.cpu["load + validate"] += time.process_time() - t
        if rng.random() < share:
            stage = "preflight"
            t = time.process_time()
            tally.counts["went through the Blender preflight"] += 1
            run_checks(cfg)
            tally.cpu["preflight"] += time.process_time() - t
        tally.counts["accepted"] += 1
        tally.outcomes["accepted"].append(path)
        for k in kinds:
            tally.input_kinds[k]["accepted"] += 1
    except (ConfigError, DataPipeError) as e:
        tally.refused(e, stage, path, kinds)
    except Hang:
        tally.failed("hang", stage, path, kinds, f"no answer within {HANG_S} s (hang)", "")
    except Exception as e:  # noqa: BLE001 - the point: anything else is a defect
        frame = traceback.extract_tb(e.__traceback__)[-1]
        where = f"{Path(frame.filename).name}:{frame.lineno} in {frame.name}"
        tally.failed("foreign exception", stage, path, kinds, f"{type(e).__name__} at {where}", str(e)[:160])
    finally:
        signal.alarm(0)


def base_presets() -> tuple[dict, dict]:
    """The demo preset as JSON and as the original add-on's input dict, mesh paths by name only
    (the generated files sit beside the presets)."""
    json_base = json.loads((C.presets_dir() / "default.json").read_text())
    for o in json_base["objects"]:
        o["filepath"] = o["filepath"].rsplit("/", 1)[-1]
    legacy_base = C.to_legacy_dict(C.default_config())
    for o in legacy_base["objects"]["objects_list"]:
        o["filepath"] = Path(o["filepath"]).name
    return json_base, legacy_base


def fuzz(args, work: Path, run_checks) -> Tally:
    """Generate args.n presets (a generated one that cannot be written is skipped) and judge each."""
    rng = random.Random(args.seed)
    files = make_files(work)
    json_base, legacy_base = base_presets()
    tally = Tally(work)
    made = 0
    while made < args.n:
        as_pickle = rng.random() < 0.3
        base = legacy_base if as_pickle else json_base
        if not as_pickle and rng.random() < 0.4:
            base = copy.deepcopy(base)
            base["structured_light"]["enabled"] = True
        raw = encode(rng, mutate(rng, base, files), as_pickle)
        if raw is None:
            tally.counts["not writable (skipped)"] += 1
            continue
        made += 1
        kinds = [k for k, marks in (("BOP models folder", (b"bop_",)), ("glTF / .glb", (b".gltf", b".glb")),
                                    ("OBJ naming a .mtl", (b"mtl_",))) if any(m in raw for m in marks)]
        path = work / f"p{made:05d}.{'pickle' if as_pickle else 'json'}"
        path.write_bytes(raw)
        judge(path, kinds, rng, args.preflight_share, tally, run_checks)
    return tally


def main(argv=None) -> None:
    ap = parser(__doc__, quick="--n 50 --preflight-share 0.2 (under a minute)")
    ap.add_argument("--n", type=int, default=3000, help="generated presets (default 3000)")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--preflight-share", type=float, default=1.0,
                    help="share of the presets validate accepts that also go through the Blender preflight")
    ap.add_argument("--cli", type=int, default=0, metavar="N",
                    help="also run N of the presets through `python -m datapipe validate` and `run` (subprocesses)")
    ap.add_argument("--out", default=None, help="the report (default benchmarks/results/fuzz_presets.md)")
    args = ap.parse_args(argv)
    if args.quick:
        args.n, args.preflight_share = 50, 0.2
    args.out = args.out or str(RESULTS / "fuzz_presets.md")

    import bpy  # noqa: F401  (the preflight's Blender; imported once)
    from datapipe.engine.gate import run_checks

    def watchdog(signum, frame):
        raise Hang()
    signal.signal(signal.SIGALRM, watchdog)

    work = Path(tempfile.mkdtemp(prefix="datapipe_fuzz_"))
    with Stopwatch() as total:
        tally = fuzz(args, work, run_checks)
    cli = cli_check(tally.outcomes, args.cli, args.seed, work) if args.cli else None
    kept = work / "foreign"
    if tally.foreign:
        kept.mkdir(exist_ok=True)
        for name, _, _ in tally.foreign:
            shutil.copy(work / name, kept / name)
    write_report(Path(args.out), args, tally, total, cli)
    print(Path(args.out).read_text())
    if tally.foreign or (cli and cli["bad"]):
        print(f"presets with foreign exceptions kept in {kept}; all presets in {work}")
    else:
        shutil.rmtree(work)


def cli_check(outcomes: dict, n: int, seed: int, work: Path) -> dict:
    """N presets through the CLI, as a user runs it: a quarter of them accepted ones (`validate`:
    exit 0, OK), the rest refused ones, drawn evenly from the stage that refused them (`validate`
    and `run --out`: exit 2, a fix, nothing written). Any traceback or other outcome is listed.
    Presets refused only for their output.path are not drawn: `run --out DIR` replaces that field,
    so the run rightly starts (and renders)."""
    import subprocess
    rng = random.Random(seed + 1)                 # its own stream: the presets above do not change
    picks = [("accepted", p) for p in rng.sample(outcomes["accepted"], min(n // 4, len(outcomes["accepted"])))]
    refused = [k for k in ("load", "validate", "preflight") if outcomes[k]]
    for i in range(n - len(picks)):
        stage = refused[i % len(refused)]
        picks.append((stage, rng.choice(outcomes[stage])))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = {"presets": len(picks), "calls": 0, "bad": [], "seconds": 0.0}
    clock = Stopwatch().start()
    for k, (stage, path) in enumerate(picks):
        out = work / f"cli_out_{k}"
        calls = [["validate", str(path)]] + ([] if stage == "accepted" else [["run", str(path), "--out", str(out)]])
        for argv in calls:
            try:
                r = subprocess.run([sys.executable, "-m", "datapipe", *argv], capture_output=True, text=True,
                                   env=env, cwd=work, errors="backslashreplace", timeout=HANG_S)
            except subprocess.TimeoutExpired:
                result["calls"] += 1
                result["bad"].append(f"{path.name} ({stage}) {argv[0]}: no answer within {HANG_S} s (hang)")
                continue
            result["calls"] += 1
            want = 0 if stage == "accepted" else 2
            ok = (r.returncode == want and "Traceback" not in r.stderr and not out.exists()
                  and ("OK" in r.stdout if want == 0 else "(fix:" in r.stderr))
            if not ok:
                result["bad"].append(f"{path.name} ({stage}) {argv[0]}: exit {r.returncode}, "
                                     f"{r.stderr.strip().splitlines()[-1][:160] if r.stderr.strip() else ''}")
    result["seconds"] = clock.stop().wall_s
    return result


def _example(foreign, kind) -> str:
    """One preset of a kind of foreign exception and its message, safe inside a Markdown table."""
    name, msg = next((p, m) for p, k, m in foreign if k == kind)
    return f"{name}: {msg!r}".replace("|", "\\|")


def write_report(out: Path, args, tally: Tally, total: Stopwatch, cli) -> None:
    n = args.n
    counts, stages, fields, foreign, cpu = tally.counts, tally.stages, tally.fields, tally.foreign, tally.cpu
    input_kinds, preflight_fields = tally.input_kinds, (tally.preflight_fields, tally.preflight_examples)
    total_cpu, wall = total.cpu_s, total.wall_s
    pf = counts["went through the Blender preflight"]
    lines = [
        "# Generated hostile presets: load + validate + Blender preflight",
        "",
        f"`benchmarks/fuzz_presets.py --n {n} --seed {args.seed} --preflight-share {args.preflight_share:g}"
        f"{f' --cli {args.cli}' if args.cli else ''}` "
        "(in process, bpy 5.0.1 module). Each preset: the demo preset (JSON) or the original add-on's input "
        "dict (pickle) with 1-4 hostile mutations (see the script's docstring), loaded with `config.load`, "
        "validated with files checked, and, for the given share of those validate accepts, put through "
        "`core.preflight.preflight` (mesh imports, the .blend read by Blender, the bin volume).",
        "",
        "| outcome | presets |",
        "|---|---:|",
        f"| generated | {n} |",
        f"| clear error (ConfigError / DataPipeError: field path + fix) | {counts['clear error']} |",
        f"| accepted (validate, and the preflight where run) | {counts['accepted']} |",
        f"| **foreign exception** (anything else) | **{counts['foreign exception']}** |",
        f"| **hang** (no answer within {HANG_S} s) | **{counts['hang']}** |",
        f"| project error without a path or a fix | {counts['project error without path or fix']} |",
        "",
        f"Through the Blender preflight: {pf} presets (every preset validate accepted, "
        f"share {args.preflight_share:g}); refused there: {stages['preflight']}. "
        f"Refused by the loader: {stages['load']}; by validate: {stages['validate']}. "
        f"Generated but not writable as JSON/pickle (skipped, not counted): {counts['not writable (skipped)']}.",
        "",
        f"Time: {wall:.0f} s wall, {total_cpu:.0f} s CPU in all (of it {cpu['load + validate']:.1f} s load + "
        f"validate of the accepted presets, {cpu['preflight']:.1f} s their preflight; the rest writes the files "
        "and refuses the others), on a shared 2-core machine.",
        "",
        "Presets naming the generated BOP models folders and glTF files (see the docstring), by outcome:",
        "",
        "| input | presets | outcomes |",
        "|---|---:|---|",
        *[f"| {k} | {sum(c.values())} | {', '.join(f'{o}: {n}' for o, n in sorted(c.items()))} |"
          for k, c in sorted(input_kinds.items())],
        "",
        "First problem's field (section.field) of the clear errors, most frequent:",
        "",
        "| field | presets |",
        "|---|---:|",
        *[f"| `{k}` | {v} |" for k, v in fields.most_common(15)],
        "",
        "Refused by the Blender preflight (validate had accepted them), by first problem:",
        "",
        "| field | presets | e.g. |",
        "|---|---:|---|",
        *[f"| `{k}` | {v} | {preflight_fields[1][k].replace('|', '/')}... |"
          for k, v in preflight_fields[0].most_common(10)],
    ]
    if cli is not None:
        lines += ["", f"Through the CLI (`--cli {args.cli}`, subprocesses): {cli['presets']} of these presets, "
                  f"{cli['calls']} calls (`validate`, and `run --out` for the refused ones) in {cli['seconds']:.0f} s; "
                  f"**{len(cli['bad'])} not as expected** (accepted: exit 0 and OK; refused: exit 2 with a fix, "
                  "nothing written; never a traceback).", *[f"- {b}" for b in cli["bad"][:20]]]
    if foreign:
        kinds = collections.Counter(kind for _, kind, _ in foreign)
        lines += ["", "## Foreign exceptions", "", "| stage: exception at (last frame) | presets | e.g. |", "|---|---:|---|",
                  *[f"| {kind} | {n} | {_example(foreign, kind)} |"
                    for kind, n in kinds.most_common()]]
    write_with_notes(out, lines)          # + fuzz_presets_notes.md (the run before the fixes)


if __name__ == "__main__":
    main(sys.argv[1:])
