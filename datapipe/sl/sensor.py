"""A seeded camera model applied to linear (noise-free) fringe renders.

Per sample, in this order (EMVA 1288 linear camera model):

1. ``electrons = radiance * electrons_per_unit`` (exposure x quantum efficiency x gain of the
   optics, folded into one scale from the render's linear radiance to photo-electrons);
2. shot noise: ``Poisson(electrons)`` (variance = mean);
3. full-well clipping at ``full_well`` electrons;
4. read noise: ``+ Normal(0, read_noise)`` electrons (dark / temporal noise, input referred);
5. ADC: ``DN = electrons / e_per_dn + black_level``, rounded to integers and clipped to
   ``[0, 2**adc_bits - 1]``; ``e_per_dn`` defaults to ``full_well / (2**adc_bits - 1)`` so the
   ADC range spans the full well.

Expected noise in DN for a mean signal S (DN above black):
``sigma^2 = S / e_per_dn + (read_noise / e_per_dn)^2 + 1/12`` (the last term only when
quantising) -- :meth:`SensorModel.noise_sigma`, usable as ``decode(noise_sigma=model.noise_sigma)``.

Randomness comes only from the ``rng_or_seed`` argument (an int seed or a numpy Generator), so
the same seed gives the same bytes, independent of Cycles' Monte-Carlo noise. Not modelled:
dark current, fixed-pattern noise / PRNU, blooming, lens blur, rolling shutter.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._errors import bad_type, bad_value

__all__ = ["SensorModel", "PRESETS"]


@dataclass(frozen=True)
class SensorModel:
    electrons_per_unit: float = 8000.0   # e- per unit of linear radiance (exposure x QE x gain)
    full_well: float = 10000.0           # e-; None/inf = no clipping
    read_noise: float = 5.0              # e- rms
    adc_bits: int | None = 12            # None = no quantisation, no ADC clipping
    shot_noise: bool = True
    e_per_dn: float | None = None        # conversion gain; None = full_well / (2**bits - 1)
    black_level: float = 0.0             # DN added before the ADC (camera's dark offset)
    output: str = "uint16"               # 'uint8', 'uint16' or 'float32' (float32 DN, also when quantised)

    @staticmethod
    def preset(name: str) -> "SensorModel":
        """A named camera. 'ideal': no noise, no quantisation, no clipping (DN = electrons =
        radiance * 1000, float32). 'industrial': a typical 1/1.8"-class global-shutter machine
        vision sensor (e.g. Sony Pregius IMX2xx: ~10 ke- full well, 2-6 e- read noise, 12-bit
        Mono12 output): 10 000 e-, 5 e-, 12 bit, radiance 1.0 -> 80% of the full well so the
        brightest fringe peaks stay just below saturation. 'industrial_8bit': the same sensor in
        Mono8 (quantisation 39 e- per DN dominates dark pixels). 'small_pixel': a 2-3 um pixel
        (4 000 e- full well, 3 e- read noise, 10 bit): more shot noise relative to signal."""
        try:
            return PRESETS[name]
        except KeyError:
            raise bad_value("preset", f"unknown sensor preset {name!r}", f"use one of {sorted(PRESETS)}") from None

    # -- derived ---------------------------------------------------------------------------
    @property
    def gain(self) -> float:
        """Electrons per DN."""
        if self.e_per_dn is not None:
            return float(self.e_per_dn)
        if self.adc_bits is None or self.full_well is None or not np.isfinite(self.full_well):
            return 1.0
        return float(self.full_well) / (2 ** int(self.adc_bits) - 1)

    @property
    def adc_max(self) -> float:
        return float(2 ** int(self.adc_bits) - 1) if self.adc_bits is not None else np.inf

    @property
    def saturation_level(self) -> float:
        """DN at/above which a sample may be clipped (full well or ADC); inf when never.

        A sample clipped at the full well reads ``fw/e_per_dn + black + read noise``; the level is
        lowered by 4 read-noise sigmas so such samples are still caught (99.997%), and is never
        above the ADC maximum."""
        g = self.gain
        fw = self.full_well if self.full_well is not None else np.inf
        lvl = min(fw / g + self.black_level - 4.0 * self.read_noise / g, self.adc_max) if np.isfinite(fw) \
            else self.adc_max
        if self.adc_bits is not None:
            lvl = float(np.floor(lvl))
        return float(lvl)

    def variance_terms(self) -> tuple[float, float, float]:
        """``(black, const, per_dn)``: :meth:`noise_sigma` squared is ``const + per_dn * max(S - black, 0)``."""
        g = self.gain
        const = (self.read_noise / g) ** 2 + (1.0 / 12.0 if self.adc_bits is not None else 0.0)
        return float(self.black_level), float(const), (1.0 / g if self.shot_noise else 0.0)

    def noise_sigma(self, signal_dn):
        """Expected temporal noise sigma (DN) at mean signal ``signal_dn`` (DN, black included)."""
        s = np.maximum(np.asarray(signal_dn, dtype=np.float64) - self.black_level, 0.0)
        g = self.gain
        var = (s / g if self.shot_noise else 0.0) + (self.read_noise / g) ** 2
        if self.adc_bits is not None:
            var = var + 1.0 / 12.0
        out = np.sqrt(var)
        return out.astype(np.float32) if isinstance(signal_dn, np.ndarray) and signal_dn.dtype == np.float32 \
            else out

    # -- simulation ------------------------------------------------------------------------
    def apply(self, images, rng_or_seed):
        """Linear radiance images (any shape, float) -> ``(digital numbers, saturation level)``.

        Returns uint16 (or float32 DN with ``output='float32'``) and the DN level at/above which
        samples must be treated as saturated (pass it as ``decode(saturation=...)``).
        """
        if isinstance(rng_or_seed, np.random.Generator):
            rng = rng_or_seed
        elif isinstance(rng_or_seed, (int, np.integer)) and not isinstance(rng_or_seed, bool):
            rng = np.random.default_rng(int(rng_or_seed))
        else:
            raise bad_type("rng_or_seed", f"must be an int seed or a numpy Generator, got {type(rng_or_seed).__name__}",
                           "pass e.g. a seed derived from (base seed, scene index)")
        x = np.asarray(images)
        if x.dtype.kind not in "uif":
            raise bad_type("images", f"has dtype {x.dtype}", "pass linear float radiance images")
        if not np.all(np.isfinite(x)) or np.any(x < 0):
            raise bad_value("images", "has NaN, inf or negative radiance",
                            "render linear, non-negative radiance (view transform Standard)")
        dtypes = {"uint8": (np.uint8, 8), "uint16": (np.uint16, 16), "float32": (np.float32, None)}
        if self.output not in dtypes:
            raise bad_value("output", f"must be one of {sorted(dtypes)}, got {self.output!r}", "pick one")
        out_dtype, max_bits = dtypes[self.output]
        if max_bits is not None and (self.adc_bits is None or self.adc_bits > max_bits):
            raise bad_value("output", f"{self.output!r} needs adc_bits <= {max_bits}", "use output='float32'")
        g = self.gain
        out = np.empty(x.shape, out_dtype)
        flat_in = x.reshape(-1)
        flat_out = out.reshape(-1)
        chunk = 1 << 20
        for s0 in range(0, flat_in.size, chunk):
            e = flat_in[s0:s0 + chunk].astype(np.float64) * self.electrons_per_unit
            if self.shot_noise:
                e = rng.poisson(e).astype(np.float64)
            if self.full_well is not None and np.isfinite(self.full_well):
                np.minimum(e, self.full_well, out=e)
            if self.read_noise > 0:
                e += rng.normal(0.0, self.read_noise, e.shape)
            dn = e / g + self.black_level
            if self.adc_bits is not None:
                np.rint(dn, out=dn)
                np.clip(dn, 0.0, self.adc_max, out=dn)
            flat_out[s0:s0 + chunk] = dn
        return out, self.saturation_level


PRESETS = {
    "ideal": SensorModel(electrons_per_unit=1000.0, full_well=None, read_noise=0.0, adc_bits=None,
                         shot_noise=False, e_per_dn=1.0, output="float32"),
    "industrial": SensorModel(),
    "industrial_8bit": SensorModel(adc_bits=8, output="uint8"),
    "small_pixel": SensorModel(electrons_per_unit=3200.0, full_well=4000.0, read_noise=3.0, adc_bits=10),
}


def _device_sensors() -> dict:
    """The calibrated sensor of every real-device preset (datapipe/devices.py) at each binning it
    offers, under the name the device fills into structured_light.sensor."""
    from ..devices import sensor_presets
    return {name: SensorModel(**fields) for name, fields in sensor_presets().items()}


PRESETS.update(_device_sensors())
