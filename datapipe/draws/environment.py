"""Environment maps (`lighting.environment`): the user's .hdr/.exr file or folder of them, their
headers checked before any work, and one map's drawn rotation and strength. No bpy (core/scene.py
builds the world from a draw).

Headers, read without decoding the pixels:
- Radiance RGBE (.hdr): Wikipedia, "Radiance (software)", section "HDR image format": "The file
  starts with the signature '#?RADIANCE'", then "a blank line signifying the end of the header. A
  single line describes the resolution and pixel order. As produced by the Radiance tools this
  always takes the form of '-Y height +X width'" (other sign/axis orders are accepted here too: the
  format's own reference is Greg Ward's radsite.lbl.gov/radiance/refer/filefmts.pdf, "Picture");
  "#?RGBE" is accepted as well (fileformats.archiveteam.org/wiki/Radiance_HDR: "some apparently
  begin with "#?RGBE" instead", e.g. files of other tools);
- OpenEXR (.exr): github.com/AcademySoftwareFoundation/openexr, src/lib/OpenEXR/ImfVersion.h: "The
  MAGIC number is stored in the first four bytes of every OpenEXR image file", MAGIC = 20000630
  (bytes 76 2f 31 01, little-endian); then the header, which the OpenEXR package reads.
"""
from __future__ import annotations

import math
import os
import re
import stat
from pathlib import Path

import numpy as np

SUFFIXES = (".hdr", ".exr")
MAX_MAPS = 10_000                     # files looked at in a folder (a library of maps, not a disk)
_EXR_MAGIC = bytes([0x76, 0x2F, 0x31, 0x01])
_HDR_IDS = (b"#?RADIANCE", b"#?RGBE")
_HDR_RES = re.compile(rb"^[+-][XY] +(\d+) +[+-][XY] +(\d+)$")
_HDR_HEADER_MAX = 64 * 1024           # a header is a few lines; more is not a Radiance picture


def header_problem(path: str | os.PathLike) -> str | None:
    """Why `path` is not a readable .hdr/.exr environment map (None when its header reads)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        return f"{p.name} is not an .hdr or .exr file"
    try:
        if not stat.S_ISREG(os.stat(p).st_mode):     # a FIFO or device would block or never end
            return f"{p.name} is not a regular file"
        with open(p, "rb") as f:
            head = f.read(_HDR_HEADER_MAX)
    except OSError as e:
        return f"cannot read {p.name}: {e.strerror or e}"
    if suffix == ".hdr":
        return _hdr_problem(p.name, head)
    if head[:4] != _EXR_MAGIC:
        return f"{p.name} does not start with the OpenEXR magic number (not an EXR file)"
    try:
        import OpenEXR
        OpenEXR.File(str(p), header_only=True).header()
    except Exception as e:          # the binding raises RuntimeError/ValueError with the library's reason
        return f"{p.name}: OpenEXR cannot read its header ({e})"
    return None


def _hdr_problem(name: str, head: bytes) -> str | None:
    lines = head.split(b"\n")
    if not lines or lines[0].strip() not in _HDR_IDS:
        return f"{name} does not start with #?RADIANCE (not a Radiance .hdr file)"
    try:
        blank = next(i for i, ln in enumerate(lines[1:-1], 1) if not ln.strip())
    except StopIteration:
        return f"{name}: no end of its Radiance header (an empty line) in the first {_HDR_HEADER_MAX // 1024} kB"
    m = _HDR_RES.match(lines[blank + 1].strip())
    if m is None or min(int(m.group(1)), int(m.group(2))) < 1:
        return f"{name}: no resolution line (like '-Y 512 +X 1024') after its Radiance header"
    return None


def find_maps(path: str | os.PathLike) -> list[str]:
    """The environment maps of `path`: itself when a file, else its .hdr/.exr files (this folder and
    below, sorted by path so that the draws do not depend on the file system's order)."""
    p = Path(path)
    if not p.is_dir():
        return [str(p)]
    out = []
    for root, dirs, files in os.walk(p):
        dirs.sort()
        out += [str(Path(root) / f) for f in sorted(files) if Path(f).suffix.lower() in SUFFIXES]
        if len(out) > MAX_MAPS:
            break
    return sorted(out)[:MAX_MAPS]


def draw_environment(lighting, maps: list[str], rng: np.random.Generator) -> dict:
    """One map of `maps`, its rotation about world Z (deg) and world strength, uniform in the
    `lighting` ranges. Drawn after the key light and ambient (their draws do not change)."""
    k = int(rng.integers(0, len(maps))) if len(maps) > 1 else 0
    lo, hi = (float(v) for v in lighting.environment_rotation_deg)
    rot = lo if hi <= lo else float(rng.uniform(lo, hi))
    lo, hi = (float(v) for v in lighting.environment_strength)
    strength = lo if hi <= lo else float(rng.uniform(lo, hi))
    return {"map": maps[k], "rotation_deg": rot, "strength": strength}


def rotation_rad(draw: dict) -> float:
    """A draw's rotation about the world's Z axis in radians (what core/scene.py gives the mapping node)."""
    return math.radians(float(draw["rotation_deg"]))
