"""The files a mesh file names (a glTF's buffers and images; an OBJ's material libraries and their
textures), checked before Blender's importer reads them. No bpy.

Blender's glTF importer reads each buffer `uri` whole (joined to the glTF's folder, so an absolute
path is taken as it stands): a uri of /dev/zero grew `validate` to 22 GiB before the kernel killed it,
a FIFO made it wait forever. So every external buffer must be a regular file within MAX_MESH_BYTES
holding at least its `byteLength`, and every external image that exists a regular file within the
same limit (a missing image is left to the importer: DataPipe refuses here only what could hang or
exhaust it, or what the importer cannot read at all). Data URIs are
inside the glTF file, whose own size is limited. The JSON of a .gltf, or the JSON chunk of a .glb
(Khronos glTF 2.0, "GLB File Format Specification": a 12-byte header `magic` "glTF", `version`,
`length`, then chunks of `chunkLength`, `chunkType` 0x4E4F534A "JSON", data), is read within
MAX_JSON_BYTES.

An OBJ names material libraries (`mtllib a.mtl`), and a .mtl names textures (`map_Kd wood.png`,
`bump`, `disp`, `refl`, `norm`); Blender's OBJ importer opens each: a FIFO as the .mtl, or as a texture
the .mtl names, hung `bpy.ops.wm.obj_import` (bpy 5.0.1, still waiting when killed after 30-40 s).
Those that exist must be regular files within MAX_MESH_BYTES; missing ones are the importer's to
report (a missing .mtl: bpy 5.0.1 logs "cannot read from MTL file" and imports the mesh).
"""
from __future__ import annotations

import json
import os
import re
import stat
import struct
from urllib.parse import unquote

from ..errors import DataPipeError
from .input_files import MAX_JSON_BYTES, MAX_MESH_BYTES, file_problem, read_json_file, read_regular

_GLB_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A


def gltf_json(path: str) -> object:
    """The glTF document of a .gltf or .glb file; DataPipeError with the reason."""
    if not path.lower().endswith(".glb"):
        return read_json_file(path, MAX_JSON_BYTES)
    head = read_regular(path, MAX_MESH_BYTES, head=20)
    if len(head) < 20 or head[:4] != _GLB_MAGIC:
        raise DataPipeError(f"{path}: not a binary glTF (it does not start with the 'glTF' header)")
    size, kind = struct.unpack("<II", head[12:20])
    if kind != _JSON_CHUNK or size > MAX_JSON_BYTES:
        raise DataPipeError(f"{path}: its first chunk is not a JSON chunk of at most {MAX_JSON_BYTES:,} bytes")
    raw = read_regular(path, MAX_MESH_BYTES, head=20 + size)[20:]
    try:
        return json.loads(raw.decode("utf-8"))
    except RecursionError:
        raise DataPipeError(f"{path}: its JSON chunk is nested too deeply to be read") from None
    except ValueError as e:                      # JSONDecodeError, UnicodeDecodeError
        raise DataPipeError(f"{path}: its JSON chunk is not valid JSON ({e})") from None


def gltf_problems(path: str) -> list[str]:
    """Why the glTF at `path` may not be handed to Blender's importer: one line per buffer or image
    that is not a regular file within the limit ('buffers[0].uri ...'); [] when it may."""
    try:
        doc = gltf_json(path)
    except DataPipeError as e:
        return [str(e)]
    if not isinstance(doc, dict):
        return [f"{path}: not a glTF document (a JSON object with 'asset', 'buffers', 'meshes' ...)"]
    base = os.path.dirname(os.path.abspath(path))
    out = []
    for key in ("buffers", "images"):
        items = doc.get(key, [])
        if not isinstance(items, list):
            out.append(f"{path}: '{key}' is not a list")
            continue
        for i, item in enumerate(items):
            where = f"{path}: {key}[{i}]"
            if not isinstance(item, dict):
                out.append(f"{where} is not a JSON object")
                continue
            uri = item.get("uri")
            n = item.get("byteLength")
            if key == "buffers" and (isinstance(n, bool) or not isinstance(n, (int, float)) or not 0 <= n <= MAX_MESH_BYTES):
                out.append(f"{where}.byteLength is {n!r}: not a size of 0..{MAX_MESH_BYTES:,} bytes")
                continue
            if uri is None or (isinstance(uri, str) and uri.startswith("data:")):
                continue                          # the .glb's own chunk, or data inside the glTF file
            if not isinstance(uri, str) or "\x00" in uri:
                out.append(f"{where}.uri is {uri!r}: not a file name")
                continue
            target = os.path.join(base, unquote(uri))
            problem = file_problem(target, MAX_MESH_BYTES)
            if problem is not None and key == "images" and problem.startswith("file not found"):
                continue                          # the importer goes on without that texture
            if problem is not None:
                out.append(f"{where}.uri {uri!r}: {problem}")
            elif key == "buffers" and os.path.getsize(target) < n:
                out.append(f"{where}.uri {uri!r}: {target} holds {os.path.getsize(target):,} bytes, fewer than "
                           f"its byteLength {int(n):,}")
    return out


_MTLLIB = re.compile(rb"^[ \t]*mtllib[ \t]+([^\r\n]+)", re.M)
_TEXTURE = re.compile(r"^\s*(map_\w+|bump|disp|decal|refl|norm)\s+(.+?)\s*$", re.M | re.I)


def obj_problems(path: str) -> list[str]:
    """Why the OBJ at `path` may not be handed to Blender's importer: one line per material library or
    texture it names that exists but is not a regular file within the limit; [] when it may."""
    base = os.path.dirname(os.path.abspath(path))
    out = []
    for lib in _obj_mtllibs(path):
        target = os.path.join(base, lib)
        problem = _existing_problem(target)
        if problem is not None:
            out.append(f"{path}: mtllib {lib!r}: {problem}")
            continue
        if not os.path.isfile(target):
            continue                                  # missing: the importer goes on without it
        try:
            text = read_regular(target, MAX_MESH_BYTES).decode("utf-8", "replace")
        except DataPipeError as e:
            out.append(f"{path}: mtllib {lib!r}: {e}")
            continue
        mtl_base = os.path.dirname(target)
        for key, rest in _TEXTURE.findall(text):
            names = {rest, rest.split()[-1]}         # options (-s 1 1 1 ...) come before the file name
            for name in sorted(names):
                problem = _existing_problem(os.path.join(mtl_base, name))
                if problem is not None:
                    out.append(f"{target}: {key} {name!r}: {problem}")
    return out


def _obj_mtllibs(path: str) -> list[str]:
    """The file names of an OBJ's `mtllib` lines (the whole rest of the line, and each blank-separated
    part), read in
    16 MiB blocks (a part mesh may be gigabytes; the file checked regular first)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    found, tail = [], b""
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return []
        while True:
            block = os.read(fd, 1 << 24)
            data = tail + block
            cut = data.rfind(b"\n") + 1 if block else len(data)    # whole lines now, the rest with the next block
            found += [m.group(1) for m in _MTLLIB.finditer(data, 0, cut)]
            tail = data[cut:]
            if not block:
                break
    finally:
        os.close(fd)
    names = []        # Blender 5.0 takes the rest of the line as one name; other readers split it at blanks
    for line in found:
        for name in [line.strip(), *line.split()]:
            if name.decode("utf-8", "surrogateescape") not in names:
                names.append(name.decode("utf-8", "surrogateescape"))
    return names


def _existing_problem(target: str) -> str | None:
    """Why an existing file named by a mesh may not be opened (not a regular file, or too large);
    None for a regular file within the limit, a missing one or a folder (neither can hang a reader)."""
    problem = file_problem(target, MAX_MESH_BYTES)
    if problem is None or problem.startswith(("file not found", "cannot read")) or os.path.isdir(target):
        return None
    return problem


def mesh_ref_problems(path: str) -> list[str]:
    """The problems of the files a mesh file names (glTF, OBJ); [] for formats that name none."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix in (".gltf", ".glb"):
        return gltf_problems(path)
    if suffix == ".obj":
        return obj_problems(path)
    return []
