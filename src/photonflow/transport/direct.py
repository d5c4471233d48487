"""Direct (unscattered) light from a point source, by quadrature: exact and noise-free.

For a source at p and sensor j (disc centre c_j, inward normal n_j, radius r_j), with
d_j = |c_j - p| and the unit direction w_j = (c_j - p) / d_j:

    mu_j = N x F_j x QE x A(theta_j) x exp(-d_j / L_abs - d_j / L_scat - d_j / L_mie)
    t_j  = t_source + d_j n_g / c

N photons emitted, F_j the fraction of them emitted towards the disc, i.e. the source's
emission density integrated exactly over the disc's solid angle
(``source.disc_fraction``: Omega_j / 4 pi for the isotropic source,
a rim integral for the diffuser's cos theta term and for the part of the disc inside a
laser's cone, so a sensor on the cone's edge gets its partial light, smoothly), QE the
global quantum efficiency, A the angular acceptance interpolated
(``response.detection.acceptance_at_cos``, linear in cos theta) at the
incidence theta_j = angle(-w_j, n_j) from the table at 0, 10, ..., 90 degrees, the
exponential the survival probability without absorption and without any scattering, n_g
the group index and c = 0.299792458 m/ns. Only sensors whose front face sees the source
(cos theta_j > 0) receive light. A and the attenuation are evaluated at the disc centre
(exact for a flat acceptance and to order (r/d)^2 otherwise). This is the light of a
sensor of relative efficiency 1 before its time offset: the sensor response
(``photonflow.response``) applies both.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..constants import SPEED_OF_LIGHT
from ..geometry.detector import Detector
from ..geometry.sensor_arrays import Sensors, sensors_for
from ..inline_jit import inline_jit
from ..numerics import strict_array, where
from ..params import Params
from ..response.detection import acceptance_at_cos


def interpolate_acceptance(table, incidence):
    """Angular acceptance at incidence angles (rad): ``acceptance_at_cos`` of their
    cosines (the one definition used by every mode)."""
    return acceptance_at_cos(table, jnp.cos(incidence))


def direct_light(detector: Detector, params: Params, source):
    """Expected photoelectrons and arrival times of direct light from a point source.

    Args:
        detector: sensors (positions m, inward normals, radii m).
        params: detector parameters (lengths m).
        source: an ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource`` (position m,
            time ns); validate it first with ``photonflow.sources.check_source``.

    Returns:
        ``(mu, arrival_time)``: (N,) expected p.e. per sensor of relative efficiency 1
        from unscattered light and (N,) arrival time of that light in ns (source time +
        d n_g / c, before the sensor's time offset; the pulse width spreads it but does
        not shift it). Sensors that do not face the source get mu = 0 (their arrival
        time is still the straight-line time).
        Differentiable with respect to every field of ``params`` and of ``source``.

    The work is done by one jitted function (``direct_light_jit``) whose arguments are
    the detector's ``Sensors``, ``params`` and ``source``, all in the dtype of
    ``params`` (and strongly typed), so new values of any of them never recompile.
    """
    dtype = jnp.result_type(params.absorption_length)
    cast = functools.partial(strict_array, dtype=dtype)
    sensors = sensors_for(detector, dtype, near=False)
    bare = Sensors(sensors.positions, sensors.normals, sensors.radius)  # no grids: none used
    return direct_light_jit(bare, params, jax.tree.map(cast, source))


@inline_jit
def direct_light_jit(sensors: Sensors, params: Params, source):
    """``direct_light`` on arrays: the detector's ``Sensors``, ``params`` and ``source``
    of one float dtype. Returns (mu p.e. at efficiency 1, time ns before offsets)."""
    centres, normals, radii = sensors.positions, sensors.normals, sensors.radius

    offset = centres - source.position  # (N, 3) source -> sensor, float32-safe
    distance = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
    direction = offset / distance[:, None]
    cos_incidence = -jnp.sum(direction * normals, axis=-1)
    facing = cos_incidence > 0

    fraction = source.disc_fraction(centres, normals, radii)
    attenuation = jnp.exp(
        -distance
        * (
            1.0 / params.absorption_length
            + 1.0 / params.scattering_length
            + 1.0 / params.mie_length
        )
    )
    acceptance = acceptance_at_cos(params.angular_acceptance, cos_incidence)
    mu = (
        source.n_photons
        * fraction
        * params.quantum_efficiency
        * acceptance
        * attenuation
    )
    mu = where(facing, mu, 0.0)
    arrival_time = source.time + distance * params.group_index / SPEED_OF_LIGHT
    return mu, arrival_time
