"""Structured light (fringe projection), pure numpy: patterns, phase, unwrapping, triangulation,
a camera noise model, the decoder and its metrics, and the scanner (sensor -> decode -> filters). No Blender here, ever (docs/CONVENTIONS.md)."""
from .decode import decode
from .decode_result import NEIGHBOUR_RISK, VALID_REASONS, DecodeResult, Reason
from .decode_setup import modulation_floor_factor
from .filters import edge_speckle_filter, multipath_filter, reflection_filter
from .fringe_basis import basis_size, frames_from_basis, pack_basis, packed_layout, quadrature_basis, unpack_basis
from .fringe_synth import (bounce_modulation, indirect_gain, pattern_profiles, projector_columns, quadrature_profiles,
                           synthesize_fringes)
from .metrics import (depth_error_stats, effective_period, pixel_depth_sigma, theoretical_depth_sigma,
                      theoretical_phase_sigma)
from .noise import estimate_noise_sigma
from .patterns import fringe_patterns, phase_shifts
from .phase import PhaseResult, phase_shift
from .response import Response, fit_response
from .scanner import Scan, Scanner
from .sensor import PRESETS, SensorModel
from .triangulate import (Triangulator, TriangulationResult, intrinsics_from_blender, intrinsics_from_blender_camera,
                          projection_matrix)
from .unwrap import UnwrapResult, plan_unwrap, unwrap_phase

__all__ = [
    "fringe_patterns", "phase_shifts",
    "phase_shift", "PhaseResult",
    "unwrap_phase", "plan_unwrap", "UnwrapResult",
    "Triangulator", "TriangulationResult", "intrinsics_from_blender_camera", "intrinsics_from_blender",
    "projection_matrix",
    "SensorModel", "PRESETS",
    "decode", "DecodeResult", "Reason", "VALID_REASONS", "NEIGHBOUR_RISK", "estimate_noise_sigma",
    "Response", "fit_response",
    "modulation_floor_factor",
    "depth_error_stats", "theoretical_phase_sigma", "theoretical_depth_sigma", "effective_period",
    "pixel_depth_sigma", "edge_speckle_filter", "multipath_filter", "reflection_filter",
    "Scanner", "Scan",
    "synthesize_fringes", "pattern_profiles", "projector_columns", "quadrature_profiles", "bounce_modulation",
    "indirect_gain", "quadrature_basis", "frames_from_basis", "basis_size", "packed_layout", "pack_basis", "unpack_basis",
]
