"""Light transport: direct light by quadrature (indirect light and sampled mode to follow)."""

from .direct import SPEED_OF_LIGHT, direct_light, direct_light_jit, interpolate_acceptance
from .solid_angle import disc_solid_angle, plane_basis

__all__ = [
    "SPEED_OF_LIGHT",
    "direct_light",
    "direct_light_jit",
    "disc_solid_angle",
    "interpolate_acceptance",
    "plane_basis",
]
