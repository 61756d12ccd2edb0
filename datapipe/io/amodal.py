"""Amodal COCO annotations (full silhouettes beside the visible masks), as UOAIS reads them. No bpy.

UOAIS (unseen object amodal instance segmentation) loads a COCO file whose annotations carry the
amodal mask in `segmentation` and the visible one beside it:
gist-ailab/uoais@8094a6c5df6e35ba42bf45162682fdc8c03b48e1:adet/data/uoais.py, `load_uoais_json`:
`obj["segmentation"] = load_segm(anno, "segmentation")`, `obj["visible_mask"] = load_segm(anno,
"visible_mask")`, `obj["occluded_mask"] = load_segm(anno, "occluded_mask")`, `obj["occluded_rate"] =
anno.get("occluded_rate", None)`; every image needs `record["depth_file_name"] =
os.path.join(image_root, img_dict["depth_file_name"])`; and `assert anno.get("ignore", 0) == 0,
'"ignore" in COCO json file is not supported.'`. Its `load_segm` converts an uncompressed RLE with
`mask_util.frPyObjects` while the module imports `pycocotools.mask as mask_utils` (a NameError), so
the masks here are COCO's compressed RLE strings (`counts` a str, pycocotools' `rleToString`), which
it passes through as they are.

The BOP export writes this second file, `scene_gt_coco_amodal.json`, beside each chunk's
`scene_gt_coco.json` (whose `segmentation` stays the visible mask, bop_toolkit's calc_gt_coco) when
asked (`output.amodal_coco`); annotations of instances with a visible pixel, no `ignore` key.
"""
from __future__ import annotations

import numpy as np

AMODAL_COCO_FILE = "scene_gt_coco_amodal.json"


def rle_counts(mask: np.ndarray) -> list[int]:
    """COCO's run lengths (column-major, starting with a run of zeros)."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    if not len(flat):
        return []
    counts = [] if not flat[0] else [0]
    change = np.flatnonzero(np.concatenate(([True], flat[:-1] != flat[1:], [True])))
    return counts + np.diff(change).tolist()


def counts_to_string(counts: list[int]) -> str:
    """pycocotools' maskApi.c rleToString: each count (from the third on, minus the count two
    before) as 5-bit groups, low first, 0x20 = more follows, sign in 0x10 of the last, + 48."""
    out = []
    for i, x in enumerate(counts):
        x = int(x) - (int(counts[i - 2]) if i > 2 else 0)
        more = True
        while more:
            c = x & 0x1F
            x >>= 5                       # arithmetic shift, as C's on a signed long
            more = (x != -1) if (c & 0x10) else (x != 0)
            if more:
                c |= 0x20
            out.append(chr(c + 48))
    return "".join(out)


def compressed_rle(mask: np.ndarray) -> dict:
    return {"size": [int(mask.shape[0]), int(mask.shape[1])], "counts": counts_to_string(rle_counts(mask))}


def amodal_annotation(image_id: int, obj_id: int, amodal: np.ndarray, visib: np.ndarray, info: dict) -> dict:
    """One UOAIS annotation: amodal `segmentation` and `bbox` (x, y, w, h, in the image), `area` of the
    amodal mask in the image, `visible_mask`, `occluded_mask` (amodal minus visible), `occluded_rate`
    (1 - scene_gt_info's visib_fract, which counts the silhouette beyond the border too)."""
    amodal = np.asarray(amodal, bool) | np.asarray(visib, bool)
    cols = np.flatnonzero(amodal.any(axis=0))
    rows = np.flatnonzero(amodal.any(axis=1))
    bbox = [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)]
    return {"image_id": int(image_id), "category_id": int(obj_id), "iscrowd": 0,
            "area": int(np.count_nonzero(amodal)), "bbox": bbox,
            "segmentation": compressed_rle(amodal), "visible_mask": compressed_rle(visib),
            "occluded_mask": compressed_rle(amodal & ~np.asarray(visib, bool)),
            "occluded_rate": float(1.0 - info["visib_fract"]),
            "height": int(amodal.shape[0]), "width": int(amodal.shape[1])}
