"""The model origin warning: a mesh whose own origin lies far from its bounding box's centre, exported
to BOP as it is (objects[i].origin = "file"). No bpy.

BOP's model frame has its origin at the centre of the 3D bounding box
(thodan/bop_toolkit@cea62d651c7e395b2e1962b9749e4e89693c6ac4:docs/bop_datasets_format.md: "the origin
coincides with the center of the 3D bounding box of the object model"); code written for BOP data
(cuboid keypoints, GDRN's extents around the origin) goes silently wrong on a model whose origin sits
at a corner or on a face. The export stays consistent either way (models, models_info.json and poses
share the mesh's frame), so this is a warning, not a refusal. "Far" = outside the box's middle half
along some axis (more than a quarter of the extent from the centre): a corner or face origin warns,
a modeller's rounding of the centre does not.
"""
from __future__ import annotations

import numpy as np

CENTRE_REGION = 0.25       # warn when |origin - centre| > this x extent along any axis


def origin_warning(where: str, field: str, lo, hi, scale: float) -> str | None:
    """The warning line for one entry (`where`, e.g. "objects[0] (obj_id 5)"; `field` its preset entry)
    whose file-unit bounding box is [lo, hi], or None."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    centre, size = (lo + hi) / 2, hi - lo
    far = np.abs(centre) > CENTRE_REGION * size
    if not far.any():
        return None
    axes = "".join(a for a, f in zip("xyz", far) if f)
    return (f"{where}: the mesh's origin lies {np.linalg.norm(centre) * scale * 1000:.3g} mm from the centre of "
            f"its bounding box (outside the box's middle half along {axes}); the BOP export keeps the file's "
            "frame, while BOP's models have their origin at that centre and code written for them (cuboid "
            f"keypoints, GDRN's extents) assumes it (fix: set {field}.origin to \"bbox_center\"; or keep \"file\" "
            "when your training code takes the file's frame)")


def origin_warnings(cfg, boxes: dict[int, tuple]) -> list[str]:
    """Warnings of an (expanded) config's entries with origin "file" when BOP output is on;
    `boxes` is {entry index: (lo, hi) in file units} as the mesh preflight measured them."""
    if "bop" not in cfg.output.formats:
        return []
    from ..io.bop_models import entry_field
    out = []
    for i, o in enumerate(cfg.objects):
        if o.origin != "file" or i not in boxes:
            continue
        where = entry_field(o, i)
        w = origin_warning(where, where.split(" ")[0], *boxes[i], float(o.scale))
        if w is not None:
            out.append(w)
    return out
