"""The files a glTF names (its buffers and images), checked before Blender's importer reads them. No bpy.

Blender's glTF importer reads each buffer `uri` whole (joined to the glTF's folder, so an absolute
path is taken as it stands): a uri of /dev/zero grew `validate` to 22 GiB before the kernel killed it,
a FIFO made it wait forever. So every external buffer must be a regular file within MAX_MESH_BYTES
holding at least its `byteLength`, and every external image a regular file within the same limit
(a missing image is the importer's to report: it imports the mesh without the texture). Data URIs are
inside the glTF file, whose own size is limited. The JSON of a .gltf, or the JSON chunk of a .glb
(Khronos glTF 2.0, "GLB File Format Specification": a 12-byte header `magic` "glTF", `version`,
`length`, then chunks of `chunkLength`, `chunkType` 0x4E4F534A "JSON", data), is read within
MAX_JSON_BYTES.
"""
from __future__ import annotations

import json
import os
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
