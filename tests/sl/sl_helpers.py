"""Small helpers shared by the structured-light tests (a unique module name: other test folders
have their own conftest.py, so tests import from here, not from conftest)."""
import numpy as np

PERIODS = (1, 8, 64)   # hierarchical default used across the tests (ratios 8: gain sqrt(65))
STEPS = 4


def decode_kw(cam, proj, periods=PERIODS, steps=STEPS, **kw):
    d = dict(periods=periods, steps=steps, P_cam=cam.P, P_proj=proj.P, proj_size=proj.size)
    d.update(kw)
    return d


def add_noise(images, sigma, seed):
    rng = np.random.default_rng(seed)
    return images + rng.normal(0.0, sigma, images.shape)
