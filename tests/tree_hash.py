"""A hash tree of a folder, for "nothing else changed" and "the same bytes as a clean run" checks
(issue #21): {relative path: sha256 | '->link target' | 'dir'}, links never followed.

`.log` files are left out and a COCO `date_created` is blanked: they say when a run ran, not what
it made."""
import hashlib
import os
import re


def hashes(root, skip=()) -> dict:
    out = {}
    for dirpath, dirs, names in os.walk(root):
        for n in dirs + names:
            p = os.path.join(dirpath, n)
            rel = os.path.relpath(p, root)
            if rel in skip or n.endswith(".log"):
                continue
            if os.path.islink(p):
                out[rel] = "->" + os.readlink(p)
            elif os.path.isdir(p):
                out[rel] = "dir"
            else:
                data = open(p, "rb").read()
                if n.endswith("_coco.json"):
                    data = re.sub(rb'"date_created": ?"[^"]*"', b'"date_created": "-"', data)
                out[rel] = hashlib.sha256(data).hexdigest()
    return out
