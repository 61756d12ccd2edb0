"""Quick-look contact sheets of a native run (no bpy; cv2 only).

`python -m datapipe show RUN_DIR [--out SHEETS_DIR] [--max N]` (arguments in datapipe/cli.py) writes, per render, one PNG

    +------------------+------------------+------------------+
    | RGB              | depth (z-buffer) | depth (struct.   |
    |                  |  colour bar, mm  |  light) same bar |
    +------------------+------------------+------------------+
    | SL - z-buffer    | instance mask    | poses: axes +    |
    |  +-R mm bar      |  (colour/index)  |  3D boxes on RGB |
    +------------------+------------------+------------------+

and one `overview.png` per run: histograms of the structured-light depth error (SL - z-buffer over
pixels where both are valid), of visib_fract over every instance (full silhouettes rasterised from
OUT/models, as the BOP writer does), and of instances per render.

`--grid N` writes instead one `grid.png`: N random renders' RGB side by side with their drawn
camera and light values, to see a run's variety at a glance.

Panel rectangles are public (`panel_rects`) so tests and tools can crop a panel.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from . import lens
from .errors import DataPipeError
from .io import layout
from .io.files import imwrite_atomic, make_dirs, read_json
from .io.models import load_models
from .visibility import visible_fractions
from .io.outdir import OutputStateError
from .sheet_draw import (BG, LEGEND, colorbar, colorize, fit_tile, hist_panel, instance_color, message_tile,
                         put_text)

PANELS = ("rgb", "depth", "sl_depth", "diff", "mask", "poses")
PAD = 8
HEADER = 34
LABEL = 22
MAX_TILE_W = 480


# ------------------------------------------------------------------------------------------------
# layout

def tile_size(width: int, height: int) -> tuple[int, int]:
    s = min(1.0, MAX_TILE_W / width)
    return max(1, int(round(width * s))), max(1, int(round(height * s)))


def panel_rects(width: int, height: int) -> dict[str, tuple[int, int, int, int]]:
    """Image area (x, y, w, h) of each panel of a sheet for a render of `width` x `height`."""
    tw, th = tile_size(width, height)
    rects = {}
    for k, name in enumerate(PANELS):
        row, col = divmod(k, 3)
        x = PAD + col * (tw + PAD)
        y = HEADER + row * (LABEL + th + LEGEND + PAD) + LABEL
        rects[name] = (x, y, tw, th)
    return rects


def sheet_size(width: int, height: int) -> tuple[int, int]:
    """(sheet width, sheet height) in pixels."""
    tw, th = tile_size(width, height)
    return 3 * tw + 4 * PAD, HEADER + 2 * (LABEL + th + LEGEND + PAD)


# ------------------------------------------------------------------------------------------------
# reading a run

def scenes_of(run_dir: Path) -> list[tuple[Path, dict]]:
    """(scene folder, scene.json) of every complete scene, in order; a foreign scene.json is refused."""
    scenes = list(layout.iter_scenes(run_dir))
    for sd, scene in scenes:
        if not _is_datapipe_scene(scene):
            raise OutputStateError(f"{sd / layout.SCENE_FILE}: not a DataPipe scene.json (no 'renders' with name, "
                                   "resolution, K) (fix: give the --out folder of a DataPipe run, or move the "
                                   "foreign file away)")
    return scenes


def _is_datapipe_scene(scene) -> bool:
    renders = scene.get("renders") if isinstance(scene, dict) else None
    return isinstance(renders, list) and all(
        isinstance(r, dict) and isinstance(r.get("name"), str) and isinstance(r.get("resolution"), list)
        and "K" in r for r in renders)


def _load_render(scene_dir: Path, rd: dict) -> dict:
    from .io.exr import read_depth, read_mask
    W, H = (int(x) for x in rd["resolution"])
    out = {"W": W, "H": H}
    p = layout.render_file(scene_dir, rd, "rgb")
    rgb = cv2.imread(str(p), cv2.IMREAD_COLOR) if p.is_file() else None
    out["rgb"] = rgb if rgb is not None else np.zeros((H, W, 3), np.uint8)
    p = layout.render_file(scene_dir, rd, "depth")
    out["depth"] = read_depth(p).astype(np.float64) * 1000.0 if p.is_file() else None
    p = layout.render_file(scene_dir, rd, "sl_depth")
    out["sl_depth"] = read_depth(p).astype(np.float64) * 1000.0 if p.is_file() else None
    p = layout.render_file(scene_dir, rd, "mask")
    out["mask"] = read_mask(p) if p.is_file() else None
    return out


def _load_models_info(run_dir: Path) -> dict[int, dict]:
    p = Path(run_dir) / layout.MODELS_DIR / layout.MODELS_INFO
    if not p.is_file():
        return {}
    return {int(k): v for k, v in read_json(p).items()}


def _valid(d):
    return np.isfinite(d) & (d > 0)


def depth_range(depth_mm: np.ndarray | None) -> tuple[float, float]:
    if depth_mm is None or not _valid(depth_mm).any():
        return 0.0, 1.0
    v = depth_mm[_valid(depth_mm)]
    lo, hi = np.percentile(v, [1, 99])
    if hi - lo < 1:
        lo, hi = lo - 0.5, hi + 0.5
    return float(lo), float(hi)


def error_range(err: np.ndarray) -> float:
    """Half-width R (mm) of the difference colour scale: the smallest of 1, 2, 5, 10, ... >= p95 |err|."""
    if err.size == 0:
        return 1.0
    p = float(np.percentile(np.abs(err), 95))
    for r in (0.5, 1, 2, 3, 5, 10, 20, 50, 100, 200, 500):
        if r >= p:
            return float(r)
    return float(math.ceil(p))


# ------------------------------------------------------------------------------------------------
# one sheet

BOX_EDGES = [(0, 1), (1, 3), (3, 2), (2, 0), (4, 5), (5, 7), (7, 6), (6, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def _draw_poses(rgb: np.ndarray, rd: dict, info: dict[int, dict], scale: float) -> np.ndarray:
    img = (rgb.astype(np.float32) * 0.6).astype(np.uint8)
    K = np.asarray(rd["K"], dtype=np.float64)
    for o in rd.get("objects", []):
        T = np.asarray(o["T_cam_obj"], dtype=np.float64)
        mi = info.get(int(o["obj_id"]))
        if mi is not None:
            lo = np.array([mi["min_x"], mi["min_y"], mi["min_z"]]) / 1000.0
            size = np.array([mi["size_x"], mi["size_y"], mi["size_z"]]) / 1000.0
            axis_len = 0.5 * float(size.max())
        else:
            lo, size, axis_len = None, None, 0.02
        pts = [np.zeros(3), [axis_len, 0, 0], [0, axis_len, 0], [0, 0, axis_len]]
        if lo is not None:
            pts += [lo + size * [i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
        P = np.asarray(pts, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]
        if (P[:, 2] <= 1e-3).any():
            continue
        d = lens.coefficients(rd.get("distortion"))
        if d is None:
            uv = P @ K.T
            uv = uv[:, :2] / uv[:, 2:] * scale
        else:                     # through the lens the image was made with (docs/CALIBRATION.md)
            xd, yd = lens.distort(P[:, 0] / P[:, 2], P[:, 1] / P[:, 2], d)
            uv = np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1) * scale
        q = [tuple(int(round(c)) for c in p) for p in uv]
        color = instance_color(int(o["mask_index"]))
        visible = o.get("px_count_visib", 1) not in (0, None) or o.get("px_count_visib") is None
        thick = 1
        if lo is not None:
            for a, b in BOX_EDGES:
                cv2.line(img, q[4 + a], q[4 + b], color if visible else (110, 110, 110), thick, cv2.LINE_AA)
        for k, c in ((1, (60, 60, 255)), (2, (60, 230, 60)), (3, (255, 120, 40))):   # x red, y green, z blue
            cv2.line(img, q[0], q[k], c, 2, cv2.LINE_AA)
        put_text(img, str(o["obj_id"]), (q[0][0] + 3, q[0][1] - 3), 0.35, color)
    return img


def render_sheet(run_dir: Path, scene_dir: Path, scene: dict, rd: dict, info: dict[int, dict] | None = None,
                 data: dict | None = None) -> np.ndarray:
    """The contact sheet of one render as a BGR image."""
    info = _load_models_info(run_dir) if info is None else info
    data = _load_render(scene_dir, rd) if data is None else data
    W, H = data["W"], data["H"]
    tw, th = tile_size(W, H)
    scale = tw / W
    SW, SH = sheet_size(W, H)
    sheet = np.full((SH, SW, 3), BG, np.uint8)
    rects = panel_rects(W, H)
    tiles, labels, legends = {}, {}, {}

    tiles["rgb"] = fit_tile(data["rgb"], tw, th)
    labels["rgb"] = "RGB"
    z = data["depth"]
    lo, hi = depth_range(z)
    sl = data["sl_depth"]
    for key, d, title, missing in (("depth", z, "depth, z-buffer", "no depth output"),
                                   ("sl_depth", sl, "depth, structured light", "structured light off")):
        if d is not None:       # both on the z-buffer's colour scale, so they compare at a glance
            tiles[key] = fit_tile(colorize(d, lo, hi), tw, th, nearest=True)
            labels[key] = f"{title} ({_valid(d).mean() * 100:.0f}% valid)"
            legends[key] = colorbar(tw, lo, hi, "mm")
        else:
            tiles[key] = message_tile(tw, th, [missing])
            labels[key] = title
    if sl is not None and z is not None:
        both = _valid(sl) & _valid(z)
        err = np.full(z.shape, np.nan)
        err[both] = sl[both] - z[both]
        R = error_range(err[both])
        tiles["diff"] = fit_tile(colorize(err, -R, R, diverging=True), tw, th, nearest=True)
        e = err[both]
        stats = f"mean {e.mean():+.2f}, std {e.std():.2f} mm" if e.size else "no overlap"
        labels["diff"] = f"SL - z-buffer: {stats}"
        legends["diff"] = colorbar(tw, -R, R, "mm", diverging=True, ticks=3)
    else:
        tiles["diff"] = message_tile(tw, th, ["structured light off"] if sl is None else ["no depth output"])
        labels["diff"] = "SL - z-buffer"
    m = data["mask"]
    if m is not None:
        cm = np.zeros((H, W, 3), np.uint8)
        for idx in np.unique(m):
            if idx > 0:
                cm[m == idx] = instance_color(int(idx))
        tiles["mask"] = fit_tile(cm, tw, th, nearest=True)
        labels["mask"] = f"instance mask ({len([i for i in np.unique(m) if i > 0])} visible)"
    else:
        tiles["mask"] = message_tile(tw, th, ["no mask output"])
        labels["mask"] = "instance mask"
    tiles["poses"] = _draw_poses(tiles["rgb"], rd, info, scale)
    labels["poses"] = f"poses: {len(rd.get('objects', []))} objects (axes x r, y g, z b)"

    for name in PANELS:
        x, y, w, h = rects[name]
        sheet[y:y + h, x:x + w] = tiles[name]
        put_text(sheet, labels[name], (x + 2, y - 7), 0.42)
        if name in legends:
            sheet[y + h:y + h + LEGEND, x:x + w] = legends[name]
    title = (f"{scene_dir.name} / {rd['name']}   image_id {rd.get('image_id')}   "
             f"{W}x{H}   {len(rd.get('objects', []))} objects   {Path(run_dir).name}")
    put_text(sheet, title, (PAD, 22), 0.55)
    return sheet


# ------------------------------------------------------------------------------------------------
# the overview

def overview_image(run_dir: str | Path, *, max_renders: int = 400) -> np.ndarray:
    """The run's overview as a BGR image (samples at most `max_renders` renders, evenly)."""
    run_dir = Path(run_dir)
    scenes = scenes_of(run_dir)
    if not scenes:
        raise DataPipeError(f"{run_dir}: no complete scene (scene.*/scene.json) to show")
    renders = [(sd, sc, rd) for sd, sc in scenes for rd in sc.get("renders", [])]
    step = max(1, math.ceil(len(renders) / max_renders))
    sample = renders[::step]
    stats = _OverviewStats()
    meshes = _run_meshes(run_dir)
    for sd, _, rd in sample:
        stats.add(_load_render(sd, rd), rd, meshes)
    panels = [_depth_error_panel(stats), _visible_fraction_panel(stats.fracs), _instances_panel(stats)]
    title = (f"{run_dir.name}: {len(scenes)} scenes, {len(renders)} renders, {sum(stats.n_all) if step == 1 else '~'} "
             f"instances" + (f" (statistics over {len(sample)} sampled renders)" if step > 1 else ""))
    return _overview_sheet(panels, title, _run_line(run_dir))


def _run_meshes(run_dir: Path) -> dict:
    """{obj_id: (vertices mm, faces)} of the run's models/ folder ({} without one, or unreadable)."""
    models = {}
    if (run_dir / layout.MODELS_DIR).is_dir():
        try:
            models = load_models(run_dir / layout.MODELS_DIR)
        except Exception:
            models = {}
    return {k: (mdl.verts_mm, mdl.faces) for k, mdl in models.items()}


class _OverviewStats:
    """What the overview's panels count over the sampled renders."""

    def __init__(self):
        self.errs, self.fracs, self.n_all, self.n_vis, self.sl_valid = [], [], [], [], []
        self.any_sl = False

    def add(self, data: dict, rd: dict, meshes: dict) -> None:
        """One render: `data` its maps (_load_render), `rd` its scene.json record."""
        z, sl, m = data["depth"], data["sl_depth"], data["mask"]
        if sl is not None and z is not None:
            self.any_sl = True
            both = _valid(sl) & _valid(z)
            e = (sl[both] - z[both]).astype(np.float32)
            if e.size > 20000:
                e = e[:: e.size // 20000 + 1]
            self.errs.append(e)
            self.sl_valid.append(float(_valid(sl).mean()))
        objs = rd.get("objects", [])
        self.n_all.append(len(objs))
        K = np.asarray(rd["K"], dtype=np.float64)
        nv = 0
        for o in objs:
            visib = int(np.count_nonzero(m == int(o["mask_index"]))) if m is not None else int(o.get("px_count_visib") or 0)
            nv += visib > 0
        stored = [o["visib_fract"] for o in objs if isinstance(o.get("visib_fract"), (int, float))]
        if objs and len(stored) == len(objs):     # the run recorded them (scene.json): no re-rasterising
            self.fracs += stored
        else:                                     # a run from before visib_fract was recorded
            self.fracs += visible_fractions(objs, m, K, meshes, data["W"], data["H"], dist=rd.get("distortion"))
        self.n_vis.append(nv)


def _depth_error_panel(stats: _OverviewStats) -> np.ndarray:
    err = np.concatenate(stats.errs) if stats.errs else np.zeros(0)
    if not (stats.any_sl and err.size):
        return hist_panel([], np.linspace(-1, 1, 3), "structured light - z-buffer depth", "error [mm]",
                           note="structured light off")
    R = error_range(err)
    e_in = err[np.abs(err) <= R]
    note = (f"mean {err.mean():+.2f} std {err.std():.2f} med|e| {np.median(np.abs(err)):.2f} "
            f"p95|e| {np.percentile(np.abs(err), 95):.2f} mm, {np.mean(stats.sl_valid) * 100:.0f}% valid")
    return hist_panel(e_in, np.linspace(-R, R, 61), "structured light - z-buffer depth",
                       f"error [mm] ({len(err)} px, {(np.abs(err) > R).mean() * 100:.1f}% beyond +-{R:g})",
                       note=note, fmt="{:+.1f}")


def _visible_fraction_panel(fracs: list) -> np.ndarray:
    if not fracs:
        return hist_panel([], np.linspace(0, 1, 11), "visible fraction per instance", "visib_fract",
                           note="no models/ folder: cannot compute full silhouettes")
    f = np.asarray(fracs)
    return hist_panel(f, np.linspace(0, 1, 11), "visible fraction per instance",
                       f"visib_fract ({len(f)} instances, {np.mean(f < 0.1) * 100:.0f}% < 0.1)",
                       note=f"median {np.median(f):.2f}, p10 {np.percentile(f, 10):.2f}, "
                            f"p90 {np.percentile(f, 90):.2f}",
                       color=(120, 210, 120), fmt="{:.2f}")


def _instances_panel(stats: _OverviewStats) -> np.ndarray:
    top = max(stats.n_all) if stats.n_all else 1
    bins = np.arange(-0.5, top + 1.5, 1.0)
    return hist_panel(stats.n_vis, bins, "instances per render (visible)",
                       f"instances (mean {np.mean(stats.n_all):.1f} annotated, {np.mean(stats.n_vis):.1f} visible)",
                       color=(230, 160, 90), integer=True)


def _run_line(run_dir: Path) -> str | None:
    """The sheet's footer from run.json (None without a readable one)."""
    run_json = run_dir / layout.RUN_FILE
    if run_json.is_file():
        try:
            rj = read_json(run_json)
            return f"seed {rj.get('seed')}   plan {len(rj.get('plan', []))} scenes   status {rj.get('status', '?')}"
        except (OSError, json.JSONDecodeError):
            pass
    return None


def _overview_sheet(panels: list[np.ndarray], title: str, footer: str | None) -> np.ndarray:
    """The panels side by side under `title`, `footer` below them."""
    ph, pw = panels[0].shape[:2]
    W = 3 * pw + 4 * PAD
    Hs = HEADER + ph + PAD + 24
    img = np.full((Hs, W, 3), BG, np.uint8)
    for k, p in enumerate(panels):
        x = PAD + k * (pw + PAD)
        img[HEADER:HEADER + ph, x:x + pw] = p
    put_text(img, title, (PAD, 22), 0.55)
    if footer is not None:
        put_text(img, footer, (PAD, Hs - 8), 0.42, (200, 200, 200))
    return img


def _imwrite(path: Path, img: np.ndarray) -> Path:
    make_dirs(path.parent)
    return imwrite_atomic(path, img)


def make_overview(run_dir: str | Path, out_path: str | Path | None = None, *, max_renders: int = 400) -> Path:
    """Write the run's overview sheet (default RUN_DIR/sheets/overview.png) and return its path."""
    run_dir = Path(run_dir)
    out_path = Path(out_path) if out_path else run_dir / layout.SHEETS_DIR / layout.OVERVIEW_FILE
    return _imwrite(out_path, overview_image(run_dir, max_renders=max_renders))


def overview_after_run(run_dir: str | Path, output) -> Path | None:
    """The overview sheet a finished run asks for (`output.overview`; OutputConfig or its dict).
    Called by the CLI, the add-on and the Ray driver after a run, never by the run engine."""
    wanted = output.get("overview", True) if isinstance(output, dict) else output.overview
    return make_overview(run_dir) if wanted else None


def sheet_name(scene_dir: Path, rd: dict) -> str:
    return f"{scene_dir.name}_{rd['name']}.png"


def make_sheets(run_dir: str | Path, out_dir: str | Path | None = None, *, max_renders: int | None = None,
                overview: bool = True) -> list[Path]:
    """One contact sheet per render (`scene.0001_render.0001.png`) plus `overview.png`.

    Returns the written paths (per-render sheets first, then the overview)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise DataPipeError(f"{run_dir}: no such run folder (fix: give the --out folder of a run)")
    out_dir = Path(out_dir) if out_dir else run_dir / layout.SHEETS_DIR
    scenes = scenes_of(run_dir)
    if not scenes:
        raise DataPipeError(f"{run_dir}: no complete scene (scene.*/scene.json) to show "
                            "(fix: give the --out folder of a run that finished at least one scene)")
    info = _load_models_info(run_dir)
    written = []
    for sd, sc in scenes:
        for rd in sc.get("renders", []):
            if max_renders is not None and len(written) >= max_renders:
                break
            written.append(_imwrite(out_dir / sheet_name(sd, rd), render_sheet(run_dir, sd, sc, rd, info)))
    if overview:
        written.append(make_overview(run_dir, out_dir / layout.OVERVIEW_FILE))
    return written


# ------------------------------------------------------------------------------------------------
# the grid: N random renders on one sheet, to see a run's variety at a glance

GRID_TILE_W = 240


def _grid_caption(scene_dir: Path, scene: dict, rd: dict) -> list[str]:
    """Tile captions: where the render is, then the drawn camera and light values when recorded."""
    lines = [f"{scene_dir.name}/{rd['name']}  {len(rd.get('objects', []))} obj"]
    cam = rd.get("camera_sampler")
    if cam:
        lines.append(f"{cam['distance']:.2f} m, tilt {cam['tilt_deg']:.0f}, roll {cam['roll_deg']:.0f} deg")
    light = rd.get("lighting") or scene.get("lighting")        # per render (lighting.per_render) or per scene
    if light:
        env = light.get("environment")
        lines.append(f"{light['key_power']:.0f} W {light['key_color_temperature']:.0f} K amb {light['ambient']:.2f}"
                     + (f" env {env['strength']:.1f}" if env else ""))
    tex = scene.get("textures")
    if tex:
        kinds = [tex[t]["kind"] for t in ("bin", "floor") if t in tex]
        lines.append("tex " + " / ".join(kinds + ([f"{len(tex['parts'])} parts"] if "parts" in tex else [])))
    return lines


def grid_image(run_dir: str | Path, n: int, *, seed: int = 0) -> np.ndarray:
    """`n` renders drawn at random (numpy seed `seed`; all of them when the run has fewer) as RGB
    tiles in a near-square grid, in scene/render order, each with its caption (BGR image)."""
    run_dir = Path(run_dir)
    if n < 1:
        raise DataPipeError(f"--grid {n}: ask for at least one render (fix: --grid 16)")
    scenes = scenes_of(run_dir)
    renders = [(sd, sc, rd) for sd, sc in scenes for rd in sc.get("renders", [])]
    if not renders:
        raise DataPipeError(f"{run_dir}: no complete scene (scene.*/scene.json) to show "
                            "(fix: give the --out folder of a run that finished at least one scene)")
    pick = sorted(np.random.default_rng(seed).choice(len(renders), size=min(n, len(renders)), replace=False))
    cols = math.ceil(math.sqrt(len(pick)))
    rows = math.ceil(len(pick) / cols)
    W, H = (int(x) for x in renders[pick[0]][2]["resolution"])
    tw, th = GRID_TILE_W, max(1, round(GRID_TILE_W * H / W))
    captions = [_grid_caption(*renders[idx]) for idx in pick]
    cap = 16 * max(3, *(len(c) for c in captions)) + 4
    img = np.full((HEADER + rows * (th + cap + PAD), PAD + cols * (tw + PAD), 3), BG, np.uint8)
    for k, idx in enumerate(pick):
        sd, sc, rd = renders[idx]
        p = layout.render_file(sd, rd, "rgb")
        rgb = cv2.imread(str(p), cv2.IMREAD_COLOR) if p.is_file() else None
        tile = fit_tile(rgb, tw, th) if rgb is not None else message_tile(tw, th, ["no rgb output"])
        row, col = divmod(k, cols)
        x, y = PAD + col * (tw + PAD), HEADER + row * (th + cap + PAD)
        img[y:y + th, x:x + tw] = tile
        for j, line in enumerate(captions[k]):
            put_text(img, line, (x + 1, y + th + 14 + 16 * j), 0.38)
    put_text(img, f"{run_dir.name}: {len(pick)} of {len(renders)} renders (seed {seed})", (PAD, 22), 0.55)
    return img


def make_grid(run_dir: str | Path, n: int, out_path: str | Path | None = None, *, seed: int = 0) -> Path:
    """Write the grid sheet (default RUN_DIR/sheets/grid.png) and return its path."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise DataPipeError(f"{run_dir}: no such run folder (fix: give the --out folder of a run)")
    out_path = Path(out_path) if out_path else run_dir / layout.SHEETS_DIR / layout.GRID_FILE
    return _imwrite(out_path, grid_image(run_dir, n, seed=seed))


def run_command(a) -> int:
    """The `show` command on its parsed arguments (run_dir, out, max, no_overview, grid, grid_seed),
    which are defined once, in datapipe/cli.py."""
    try:
        if a.grid is not None:
            out = Path(a.out) / layout.GRID_FILE if a.out else None
            print(f"grid written to {make_grid(a.run_dir, a.grid, out, seed=a.grid_seed)}")
            return 0
        paths = make_sheets(a.run_dir, a.out, max_renders=a.max, overview=not a.no_overview)
    except DataPipeError as e:
        print(f"datapipe: error: {e}", file=sys.stderr)
        return 1 if isinstance(e, OutputStateError) else 2
    print(f"{len(paths)} sheet(s) written to {paths[0].parent if paths else a.out}")
    return 0

