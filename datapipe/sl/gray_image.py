"""The scanner's own 2D image (render output `sl_gray`, BOP's gray_{sensor}/): the fringe-mean image.

A phase-shifting scanner's patterns are 1/2 + 1/2 cos(...) with equally spaced shifts, so the mean
of a frequency's N captured frames is the image under a uniform half-white projector (plus the
ambient light), the "texture" or grey image such scanners deliver beside the depth. Here it is the
mean of all F x N column-fringe frames the decoder read (not the row code): the very captures, at
the capture's exposure (the base exposure; with HDR the fused frames, in its DN units), with their
shot, read and quantisation noise (averaging F x N frames divides its sigma by sqrt(F x N)).

Written as the sensor model's digital numbers, rounded and clipped to its ADC range: uint8 for a
sensor of at most 8 bits, else uint16 holding the raw DN (a 12-bit sensor gives 0..4095, not
scaled to 16 bits; black level included). A sensor without an ADC ('ideal', float DN) is clipped
to 0..65535.
"""
from __future__ import annotations

import numpy as np


def fringe_mean(images: np.ndarray, n_fringe: int, adc_bits: int | None) -> np.ndarray:
    """(>= n_fringe, H, W) captured frames in DN -> the (H, W) grey image (see the module doc)."""
    frames = np.asarray(images)[:n_fringe]
    mean = frames.astype(np.float64).mean(axis=0)
    bits = 16 if adc_bits is None else int(adc_bits)
    dtype = np.uint8 if bits <= 8 else np.uint16
    top = min(2.0 ** bits - 1, float(np.iinfo(dtype).max))
    return np.clip(np.rint(np.nan_to_num(mean, nan=0.0)), 0.0, top).astype(dtype)
