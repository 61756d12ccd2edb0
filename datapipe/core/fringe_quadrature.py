"""`QuadratureFringes`, `structured_light.fringe_mode` "quadrature": the path-traced lights of
core/fringe_render.py showing a white image and a cos and a sin image per period (1 + 2F images
instead of F x N, + 2 instead of N for the row code), every phase step mixed from them
(sl/fringe_basis.py: light is linear in the projected image; one seed, so the render mode's very
paths: the same frames up to float rounding, mirror images included).

Two variants, chosen by constructor argument from the run's FringePlan (config/plan.py):
`packed` travels the images three to a light, one per colour channel (sl.pack_basis; 4 layers
instead of 9 with the default periods and the row code; a layer costs its paths whatever it emits,
so the call costs ~4/9 of the unpacked one, benchmarks/results/sl_glossy_modes.md), which the plan
chooses where every configured material is grey (config/plan.py grey_materials); the plan's `calls`
are one Cycles call on the render mode's point grid (shipped), or with a coarse supersample of 1 the
coarse periods in a second call at the camera grid (a quarter of their paths; measured in
benchmarks/results/sl_glossy_modes.md, never picked by `auto`).
"""
from __future__ import annotations

import time

import numpy as np

from .. import sl
from ..config.plan import QuadCall, quad_call_layers
from .fringe_call import block_mean
from .fringe_render import GREY_SUFFIX, FRINGE_BASENAME, PatternLights
from .projector import AMBIENT_LAYER


class QuadratureFringes(PatternLights):
    """White + (cos, sin) per frequency in each of `calls` (FringePlan.quad_calls), one image per
    layer or, `packed`, three (one per colour channel)."""

    def __init__(self, cam, *, packed: bool, calls: list[QuadCall]):
        super().__init__(cam)
        self.packed = bool(packed)
        self.calls = list(calls)

    def _layout(self, call: QuadCall, rows: bool = True) -> list[tuple]:
        """A call's packed layers (sl.packed_layout): the basis image in each channel."""
        return sl.packed_layout(len(call.periods), len(call.rows) if rows else 0)

    def patterns(self) -> np.ndarray:
        Wp, Hp = self.cam.proj_size
        if self.cam.cfg.structured_light.projector_gamma != 1.0:
            raise ValueError("fringe_mode 'quadrature' needs a linear projector (projector_gamma 1)")
        patterns = [sl.quadrature_basis(Wp, Hp, c.periods, row_periods=c.rows) for c in self.calls]
        if self.packed:
            patterns = [sl.pack_basis(b, self._layout(c)) for b, c in zip(patterns, self.calls)]
        return np.concatenate(patterns)

    def white_layers(self) -> list[int]:
        """Indices (in `layers`) of each call's white layer, the first of its layers (packed only:
        one image per layer writes every layer as grey)."""
        if not self.packed:
            return []
        out, i = [], 0
        for c in self.calls:
            out.append(i)
            i += quad_call_layers(c, self.packed)
        return out

    def light_gains(self) -> list:
        """(modulation a bounce keeps, the image's mean) of each light, per call: the white image,
        then a (cos, sin) pair per frequency; packed, per channel. A white image is shared by
        frequencies whose bounce gains differ: it gets gain 0 (its bounce light is `alpha`, the
        image's mean times its opacity), what the mixed frames need wherever the image is opaque
        (sl/fringe_basis.py), and the finest fringe (gain ~0: the depth) matches the render mode's
        also in the image's faded outer half texel, where the coarse ones differ by gain x the fade
        (up to 1% of the peak on 6 of 4800 pixels of a mirror scene, measured)."""
        Wp, Hp = self.cam.proj_size
        out = []
        for c in self.calls:
            images = [(0.0, 1.0)] + [(self.gain(K, Wp), 0.5) for K in c.periods for _ in range(2)]
            images += [(self.gain(K, Hp), 0.5) for K in c.rows for _ in range(2)]
            if not self.packed:
                out += images
                continue
            for chans in self._layout(c):      # per channel; an unused one emits nothing
                pairs = [images[j] if j is not None else (0.0, 0.0) for j in chans]
                out.append((tuple(p[0] for p in pairs), tuple(p[1] for p in pairs)))
        return out

    def render(self, render_dir, seed: int, T_world_cam, rows: bool):
        """Each call (its row-code images only with `rows`), every phase step mixed from its white,
        cos and sin images (same seed: same paths) -> the render mode's stack layout (periods in
        config order, then the row code), wall seconds, the projector-off image (first call)."""
        self.check_rows(rows)
        plan, steps = self.cam.plan, self.cam.plan.steps
        frames, seconds, i, ambient_image = {}, 0.0, 0, None
        for g, call in enumerate(self.calls):
            ambient = plan.ambient and g == 0     # the first call is at `supersample`, the fringes' grid
            with_rows = rows and bool(call.rows)
            names = self.layer_names[i:i + quad_call_layers(call, self.packed, rows=with_rows)]
            i += quad_call_layers(call, self.packed)
            n_images = sl.basis_size(len(call.periods), rows=with_rows)
            what = (f"{len(names)} quadrature layers ({n_images} images: white + cos, sin of {len(call.periods)} "
                    f"periods" + (" + the row code" if with_rows else "")
                    + (", three per layer in R, G, B)" if self.packed else ")"))
            if self.packed:
                stack, sec, amb = self._render_packed(names, self._layout(call), render_dir, seed, call.supersample,
                                                      what, ambient)
            else:
                stack, sec, amb = self.render_layers(names, render_dir, seed, call.supersample, what, ambient)
            ambient_image = amb if ambient else ambient_image
            t0 = time.perf_counter()
            mixed = sl.frames_from_basis(stack, steps)
            seconds += sec + time.perf_counter() - t0
            keys = [("x", K) for K in call.periods] + ([("y", K) for K in call.rows] if with_rows else [])
            frames.update({k: mixed[j * steps:(j + 1) * steps] for j, k in enumerate(keys)})
        order = [("x", K) for K in plan.periods] + ([("y", K) for K in plan.row_periods] if rows else [])
        return np.concatenate([frames[k] for k in order]), seconds, ambient_image

    def _render_packed(self, names, layout, render_dir, seed: int, ss: int, what: str, ambient: bool = False):
        """Packed layers `names` (white first) in one isolated Cycles call -> (the basis radiance
        (n, H, W) float32 at the camera resolution, grey as if each image were rendered alone:
        sl.unpack_basis per point sample, then the block mean (over one path the ratio to the white
        image is exact, whatever its colour); wall seconds; the projector-off image with `ambient`)."""
        from . import compat

        extra = [AMBIENT_LAYER] if ambient else []
        seconds = self.isolated_call(names + extra, render_dir, seed, ss, what, ambient)
        t0 = time.perf_counter()
        grey_name = names[0] + GREY_SUFFIX
        expect = [f"{n}.{c}" for n in names for c in "RGB"] + [f"{grey_name}.V"] + [f"{n}.V" for n in extra]
        ch = compat.take_written_exr(render_dir, FRINGE_BASENAME, "fringe", expect=expect)
        amb = block_mean(ch.pop(f"{AMBIENT_LAYER}.V")[None].astype(np.float32), ss)[0] if ambient else None
        grey = ch.pop(f"{grey_name}.V")
        rgb = np.empty((len(names), 3) + grey.shape, np.float32)      # planar, as the EXR holds them
        for li, n in enumerate(names):
            for c, cn in enumerate("RGB"):
                rgb[li, c] = ch.pop(f"{n}.{cn}")
        basis = sl.unpack_basis(rgb, grey, layout)
        del rgb, ch
        return block_mean(basis, ss), seconds + time.perf_counter() - t0, amb
