"""What the decoder returns: the per-pixel :class:`Reason` codes and the :class:`DecodeResult` maps
(made by :func:`datapipe.sl.decode.decode`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from .triangulate import Triangulator

__all__ = ["Reason", "VALID_REASONS", "NEIGHBOUR_RISK", "DecodeResult"]


class Reason(IntEnum):
    """Why a pixel has no depth (uint8 in :attr:`DecodeResult.reason`), or how a valid one got it
    (VALID: its own frequencies; NEIGHBOUR_ORDER: its order from its neighbours). When several
    apply, the first of INVALID_INPUT, SATURATED, NO_LIGHT, INCONSISTENT, BAD_ORDER, ILL_CONDITIONED,
    OUTSIDE_PROJECTOR is reported (the more basic cause first)."""
    VALID = 0
    NO_LIGHT = 1            # modulation below the noise floor, or contrast B/A too low
    SATURATED = 2           # fewer than 3 unsaturated samples in some frequency
    BAD_ORDER = 3           # probability of a wrong fringe order above max_wrong, even with the neighbours' help
    OUTSIDE_PROJECTOR = 4   # behind the projector or outside its other image axis
    ILL_CONDITIONED = 5     # camera ray (nearly) in a projector column plane: |dZ/dx| over the cap
    INVALID_INPUT = 6       # NaN or inf in a sample
    FILTERED = 7            # removed by a post-filter outside the decoder (the pipeline's edge/speckle filter)
    MULTIPATH = 8           # removed by the local reflection filters (sl.filters: multipath_filter,
                            # global_light_filter, bounce_island_filter)
    INCONSISTENT = 9        # the frequencies disagree by more than the noise allows (aliasing, mixed pixel,
                            # inter-reflection, tone curve): see datapipe.sl.confidence
    REFLECTION = 10         # removed by the global reflection filter: the row-coded patterns say the light
                            # left the projector from another row than the decoded point's (a mirror ghost,
                            # sl.filters.reflection_filter)
    NEIGHBOUR_ORDER = 11    # VALID, but the fringe order came from confident neighbours on the same surface
                            # (sl.spatial), not from the pixel's own frequencies alone; its confidence is
                            # lowered by NEIGHBOUR_RISK


VALID_REASONS = (Reason.VALID, Reason.NEIGHBOUR_ORDER)   # reason codes of pixels with depth
NEIGHBOUR_RISK = 1e-3   # subtracted from a neighbour-filled pixel's confidence: the chance that the surface
                        # does not continue through it despite the same-surface tests (sl.spatial); on the
                        # adversarial scenes of tests/sl/test_sl_trust.py the measured share is below it



@dataclass
class DecodeResult:
    """Decoded maps, all (H, W) unless noted. NaN marks invalid pixels in depth/points/proj_x/phase."""
    depth: np.ndarray                 # float32, metres along the camera z axis
    valid: np.ndarray                 # bool
    proj_x: np.ndarray                # float32 projector coordinate (column for axis='x'), pixels
    modulation: np.ndarray            # (F, H, W) float32, per frequency, image units
    offset: np.ndarray                # float32, mean offset A over the frequencies, image units
    wrapped: list                     # F arrays (H, W) float32 in [0, 2*pi)
    phase: np.ndarray                 # float32 absolute phase of the finest frequency
    reason: np.ndarray                # uint8, see Reason
    order_error: np.ndarray           # float32 in [0, 0.5]: distance of the order estimate from an integer
    confidence: np.ndarray | None = None  # float32: probability that the fringe orders are right (0 where
                                          # no order was decoded: NO_LIGHT, SATURATED, INVALID_INPUT;
                                          # NEIGHBOUR_ORDER pixels: lowered by NEIGHBOUR_RISK)
    periods: tuple = ()
    steps: int = 0
    method: str = ""
    noise_sigma: float | None = None  # scalar noise sigma used for the floor (None if per-pixel)
    modulation_floor: float | None = None   # scalar floor used (None if per-pixel)
    extras: dict = field(default_factory=dict)
    triangulator: Triangulator | None = field(default=None, repr=False)
    _points: np.ndarray | None = field(default=None, init=False, repr=False)

    @property
    def points(self) -> np.ndarray:
        """(H, W, 3) float32 camera-frame points (OpenCV), metres, NaN where invalid. Computed
        from ``depth`` and the camera rays on first access (saves 12 bytes per pixel otherwise)."""
        if self._points is None:
            self._points = self.triangulator.points(self.depth)
        return self._points

    def reason_counts(self) -> dict[str, int]:
        counts = np.bincount(self.reason.ravel(), minlength=max(Reason) + 1)
        return {r.name: int(counts[r.value]) for r in Reason}
