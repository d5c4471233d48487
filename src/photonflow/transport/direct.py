"""Direct (unscattered) light from a point source, by quadrature: exact and noise-free.

For a source at p and sensor j (disc centre c_j, inward normal n_j, radius r_j), with
d_j = |c_j - p| and the unit direction w_j = (c_j - p) / d_j:

    mu_j = N x S(w_j) x Omega_j x QE x eff_j x A(theta_j)
           x exp(-d_j / L_abs - d_j / L_scat - d_j / L_mie)
    t_j  = t_source + d_j n_g / c + offset_j

N photons emitted, S the source's emission density (photons / sr / photon), Omega_j
the exact solid angle of the disc (``disc_solid_angle``), QE the global quantum
efficiency, eff_j the sensor's relative efficiency, A the angular acceptance
linearly interpolated in the incidence angle theta_j = angle(-w_j, n_j) from the
table at 0, 10, ..., 90 degrees (held at its end values outside), the exponential the
survival probability without absorption and without any scattering, n_g the group
index and c = 0.299792458 m/ns. Only sensors whose front face sees the source
(cos theta_j > 0) receive light. S and A are evaluated at the disc centre (exact for
the isotropic source and a flat acceptance; otherwise accurate to order (r/d)^2).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from ..geometry.detector import Detector
from ..params import N_ACCEPTANCE_ANGLES, Params
from .solid_angle import DEFAULT_NODES, disc_solid_angle

#: Speed of light in vacuum, m/ns.
SPEED_OF_LIGHT = 0.299792458
#: Spacing of the angular-acceptance table, rad (10 degrees).
ACCEPTANCE_STEP = math.radians(10.0)


def interpolate_acceptance(table, incidence):
    """Linear interpolation of the (10,) acceptance table (0, 10, ..., 90 deg) at angles (rad).

    Angles beyond 90 degrees take the last entry. Differentiable in ``table`` and, away
    from the table nodes, in ``incidence``.
    """
    position = jnp.clip(incidence / ACCEPTANCE_STEP, 0.0, N_ACCEPTANCE_ANGLES - 1.0)
    lower = jnp.clip(jnp.floor(position), 0, N_ACCEPTANCE_ANGLES - 2).astype(jnp.int32)
    weight = position - lower.astype(position.dtype)
    return table[lower] * (1.0 - weight) + table[lower + 1] * weight


def _safe_norm(vectors):
    """|v| along the last axis with a zero (not NaN) gradient at v = 0."""
    squared = jnp.sum(vectors * vectors, axis=-1)
    positive = squared > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squared, 1.0)), 0.0)


def direct_light(detector: Detector, params: Params, source):
    """Expected photoelectrons and arrival times of direct light from a point source.

    Args:
        detector: sensors (positions m, inward normals, radii m).
        params: detector parameters (lengths m, time offsets ns).
        source: an ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource`` (position m,
            time ns); validate it first with ``photonflow.sources.check_source``.

    Returns:
        ``(mu, arrival_time)``: (N,) expected p.e. per sensor from unscattered light and
        (N,) arrival time of that light in ns (source time + d n_g / c + time offset;
        the pulse width spreads it but does not shift it). Sensors that do not face the
        source get mu = 0 (their arrival time is still the straight-line time).
        Differentiable with respect to every field of ``params`` and of ``source``.

    The work is done by one jitted function (``direct_light_jit``) whose arguments are
    the sensor arrays, ``params`` and ``source``, all cast to the dtype of ``params``
    (and made strongly typed) first, so new values of any of them never recompile.
    """
    dtype = jnp.result_type(params.absorption_length)

    def cast(leaf):
        return jnp.asarray(leaf, dtype=dtype) + jnp.zeros((), dtype)  # drops weak typing

    return direct_light_jit(
        cast(detector.sensor_positions),
        cast(detector.sensor_normals),
        cast(detector.sensor_radius),
        params,
        jax.tree.map(cast, source),
    )


@jax.jit
def direct_light_jit(sensor_positions, sensor_normals, sensor_radius, params: Params, source):
    """``direct_light`` on arrays: (N, 3) sensor centres m, (N, 3) inward unit normals,
    (N,) disc radii m, ``params`` and ``source`` of one float dtype. Returns (mu, time ns)."""
    centres, normals, radii = sensor_positions, sensor_normals, sensor_radius

    offset = centres - source.position  # (N, 3) source -> sensor, float32-safe
    distance = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
    direction = offset / distance[:, None]
    cos_incidence = -jnp.sum(direction * normals, axis=-1)
    sin_incidence = _safe_norm(jnp.cross(direction, normals))
    incidence = jnp.arctan2(sin_incidence, cos_incidence)
    facing = cos_incidence > 0

    solid_angle = disc_solid_angle(source.position, centres, normals, radii, n_nodes=DEFAULT_NODES)
    attenuation = jnp.exp(
        -distance
        * (
            1.0 / params.absorption_length
            + 1.0 / params.scattering_length
            + 1.0 / params.mie_length
        )
    )
    acceptance = interpolate_acceptance(params.angular_acceptance, incidence)
    mu = (
        source.n_photons
        * source.emission_density(direction)
        * solid_angle
        * params.quantum_efficiency
        * params.efficiency
        * acceptance
        * attenuation
    )
    mu = jnp.where(facing, mu, 0.0)
    arrival_time = source.time + distance * params.group_index / SPEED_OF_LIGHT + params.time_offset
    return mu, arrival_time
