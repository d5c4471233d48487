"""Direct (unscattered) light of a particle track, by quadrature in the angle to the track.

A track starts at x0 (m) along the unit direction d; its emission model
(``photonflow.emission``, one energy) gives rho(s, cos) = d^2N / ds dcos, the photons per
m along d per unit cos(angle to d), uniform in azimuth, for 0 <= s <= S (the light's
extent). For sensor j (disc centre p_j, inward normal n_j, radius r_j) at distance a
along d and b across it from x0, the point s of the track sees the sensor at
cos(theta) = (a - s) / sqrt((a - s)^2 + b^2), a monotonic function of s, so

    mu_j = int_{u1}^{u0} rho(s(u), u) / (2 pi) x Omega_j x |ds/du| x QE x A(theta_in)
           x exp(-rate_total L) du,   s(u) = a - b u / sqrt(1 - u^2),
    |ds/du| = b / (1 - u^2)^(3/2),

with u0 (u1) the cosine seen from s = 0 (s = S), L the distance from the emission point
to the disc centre, Omega_j = cos_in 2 pi r_j^2 / (R (R + L)) with R = sqrt(L^2 + r_j^2)
(the on-axis disc solid angle tilted by the incidence cosine cos_in), A the angular
acceptance, and rho averaged over the disc's footprint in cos: seen from the emission
point, the disc is an ellipse of semi-axes r_j / R and r_j cos_in / R, whose extent along
the angle theta to the track is w_theta = (r_j / R) sqrt(1 - (e_theta . n_j)^2), and
rho is averaged over a semicircle of half-width w = sin(theta) w_theta in cos
(``EmissionSlice.density``'s ``width``; the catch of a Cherenkov peak narrower than the
disc is the peak's light times the chord of the footprint it crosses). Near a sensor
(a few of its radii) neither the footprint nor the disc's solid angle is small: the
sensors seen nearest are split into sub-discs (``NEAR_SENSORS``). The integral runs in
u because the Cherenkov peak is sharp in u. Its panels end at
fixed cosines (``PANEL_BREAKS``, dense over the Cherenkov peaks) clipped to [u1, u0],
and at the cosines under which the sensor sees the emission model's knots along the
track (so no panel straddles a knot of the model's splines in s); sorted per sensor,
each panel is integrated by ``NODES_PER_PANEL``-point Gauss-Legendre. Every sensor gets
nodes on the peak, and the panels move continuously with the track, so the light is a
smooth function of the track (no stripes when it moves by a millimetre). The fixed
cosines are ``PANEL_BREAKS`` (dense over the peaks of every medium and speed) only for
the near field's sub-discs; every other disc sees the track from afar, within a narrower
range of cos, where the knots' panels resolve the peak, and gets a few breaks about the
emission model's peak instead (``PEAK_BREAKS``): 38 instead of 52 panels (isotropic
light, which has no peak, keeps ``PANEL_BREAKS`` everywhere). On SK (a 1 GeV
muon) the light-weighted rms error against an 8-point rule on all the breaks is 0.004 %.
b is softened to sqrt(b^2 + (r_j / 4)^2), so a track aimed at a sensor stays finite
(a relative error ~(r_j / 4 b)^2: 0.25 % at 5 disc radii, where TAO's 2.8 cm tiles
sit a few cm from a track; the nearest discs are split into sub-discs anyway).

The arrival time of the light of node s is t0 + s / c + tau(s) + L n_g / c, with tau the
emission-time offset of the model (mean and variance per s: the particle's slowing down
and its secondaries); the direct light is ``DIRECT_COMPONENTS`` Gaussian components, each
moment-matched to the light of one stretch of the part of the track whose light reaches
the detector (cut at knots of the model, scaled into that part where the wall ends it),
so that a sensor that sees a long stretch of track gets the shape of its arrival times,
not one wide Gaussian.
All of it is the light of a sensor of relative efficiency 1 before
its time offset. Lengths m, times ns.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import SPEED_OF_LIGHT
from ..geometry.sensor_arrays import Sensors
from ..numerics import safe_sqrt, smoothstep, where
from ..response.detection import acceptance_at_cos
from .optics import interaction_rates, orthonormal_basis, travel_time

#: Panel boundaries in cos(angle to the track): 0.01-0.02 wide over the Cherenkov peaks
#: of water (~0.74) and scintillator (~0.67) and of slower particles (up to ~0.95).
PANEL_BREAKS = np.array([-1.0, -0.6, -0.2, 0.2, 0.4, 0.5, 0.56, 0.62, 0.65, 0.67, 0.69,
                         0.71, 0.72, 0.73, 0.74, 0.75, 0.76, 0.78, 0.8, 0.83, 0.86, 0.9,
                         0.94, 0.97, 1.0])
#: Panel boundaries of every disc but the near field's sub-discs, in cos relative to
#: the emission model's peak (``peak_cos``), besides the cosines of the model's knots
#: along the track and the ends of the sensor's range. Seen from afar, a track spans
#: ~0.1-0.3 in cos and its knots' panels, narrower than any fixed ones, resolve the
#: peak alone; a long track (5 GeV in SK) or a small detector (IWCD) leaves wide knot
#: panels near the peak, which these split. Measured in float64 against an 8-point rule
#: on ``PANEL_BREAKS`` and the knots, light-weighted rms over the sensors: SK (200 MeV-5
#: GeV mu-, 500 MeV-2 GeV e-, at the centre and near the walls) and IWCD at most 7e-4
#: (with ``PANEL_BREAKS`` for every disc: 5e-4), the Cherenkov light of TAO's crossing
#: 1 GeV muon 4.9e-3 (3.0e-3), with 38 instead of 52 panels.
PEAK_BREAKS = np.array([-0.08, -0.04, -0.02, -0.01, 0.0, 0.01, 0.02, 0.04, 0.08])
#: Gauss-Legendre nodes per panel.
NODES_PER_PANEL = 2
#: Sensors refined by sub-discs (the near field): a disc seen from a few of its radii
#: away is not a point, nor is the Cherenkov ring straight across it, so the
#: ``NEAR_SENSORS`` discs with the largest angular radius r / d seen from the track's
#: light (d: the distance to the segment from the start to the light's end; weight 0
#: below ``NEAR_FROM`` rad or the next disc's, rising smoothly to 1 within
#: ``NEAR_FULL`` - ``NEAR_FROM`` above that) are split into equal-area sub-discs in
#: ``SUB_DISC_RINGS`` rings around a centre one (37 for 3), each integrated as a disc.
NEAR_SENSORS = 48
#: ... at most one sensor in this many (a toy detector of 200 sensors refines 12, not a
#: quarter of them; every preset has enough sensors for all 48).
NEAR_SHARE = 16
NEAR_FROM = 0.04
NEAR_FULL = 0.08
SUB_DISC_RINGS = 3
#: Arrival-time components of the direct light: the light of this many stretches of the
#: track's visible part (``_stretch_cuts``), each moment-matched to its nodes' times.
DIRECT_COMPONENTS = 4


def _panel_rule():
    """Nodes (in [0, 1]) and weights of the Gauss-Legendre rule on one panel."""
    nodes, weights = np.polynomial.legendre.leggauss(NODES_PER_PANEL)
    return 0.5 * (nodes + 1.0), 0.5 * weights


def peak_cos(emission, sharpness: float = 8.0):
    """The cos (to the track) around which ``emission`` sends most light: the soft
    maximum of its angular profile over its cos knots (weights profile^``sharpness``,
    smooth in the energy), or None for isotropic light (a model without angular knots).
    Not differentiated (it only places quadrature panels)."""
    profile = jax.lax.stop_gradient(emission.cos_profile())
    if profile.shape[0] < 3:
        return None
    tiny = jnp.finfo(profile.dtype).tiny
    weight = (profile / jnp.maximum(jnp.max(profile), tiny)) ** sharpness
    return jnp.sum(weight * emission.cos) / jnp.maximum(jnp.sum(weight), tiny)


def _peak_breaks(emission, dtype):
    """(P,) panel breaks in cos of the discs outside the near field: -1, 1 (each sensor's
    range ends, after clipping) and ``PEAK_BREAKS`` about the model's ``peak_cos``;
    ``PANEL_BREAKS`` for isotropic light (no peak: its light at a near sensor comes from
    all angles)."""
    peak = peak_cos(emission)
    if peak is None:
        return jnp.asarray(PANEL_BREAKS, dtype)
    return jnp.concatenate([jnp.asarray([-1.0, 1.0], dtype),
                            jnp.clip(peak.astype(dtype) + jnp.asarray(PEAK_BREAKS, dtype),
                                     -1.0, 1.0)])


def _seen_cos(ahead, across):
    """cos(angle to the track) under which a sensor ``ahead`` m along and ``across`` m
    off a point of the track sees it."""
    return ahead / jnp.sqrt(ahead * ahead + across * across)


def track_direct_light(sensors: Sensors, params, position, direction, time, emission,
                       length=None):
    """Direct light of one track at every sensor (module docstring).

    Args:
        sensors: the detector's ``Sensors`` (centres m, inward normals, radii m).
        params: detector parameters (attenuation lengths m, QE, acceptance, group index).
        position: (3,) track start, m. direction: (3,) unit vector. time: start, ns.
        emission: the track's ``EmissionSlice`` (its energy's emission model).
        length: light is emitted only for s <= length (m; the distance to the wall along
            the track: light made beyond the wall never enters the detector); None:
            the whole extent.

    Returns:
        (charge (N, C) p.e. of sensors of efficiency 1, mean arrival times (N, C) ns,
        variances of the arrival times (N, C) ns^2) of C = ``DIRECT_COMPONENTS``
        components; a component without light gets the time of light from the track
        start and variance 0.
    """
    extent = emission.extent if length is None else jnp.minimum(emission.extent, length)
    light = disc_light_of(params, position, direction, time, emission, extent)
    near = near_field_size(sensors)
    if near <= 0:
        return light(sensors.positions, sensors.normals, sensors.radius, breaks=PANEL_BREAKS)
    base = light(sensors.positions, sensors.normals, sensors.radius,
                 breaks=_peak_breaks(emission, sensors.positions.dtype))
    return refine_near_field(base, sensors, nearness(sensors, position, direction, extent),
                             light, near)


def disc_light_of(params, position, direction, time, emission, extent):
    """``_disc_light`` of one track (extent m: where its light ends): a function of the
    discs (centres (N, 3) m, normals (N, 3), radii (N,) m) and ``breaks``."""
    return functools.partial(_disc_light, params=params, position=position,
                             direction=direction, time=time, emission=emission, extent=extent)


def near_field_size(sensors: Sensors) -> int:
    """Number of discs refined by sub-discs (``NEAR_SENSORS``, at most one in
    ``NEAR_SHARE``); 0 for a detector of fewer than ``NEAR_SHARE`` sensors."""
    return min(NEAR_SENSORS, sensors.positions.shape[0] // NEAR_SHARE)


def nearness(sensors: Sensors, position, direction, extent):
    """(N,) each disc's angular radius r / d seen from the track's light (d: its distance
    to the segment from the start to ``extent`` m along the track, at least r)."""
    offset = sensors.positions - position
    along = jnp.clip(offset @ direction, 0.0, extent)
    across = offset - along[:, None] * direction
    gap = safe_sqrt(jnp.sum(across * across, axis=1))
    return sensors.radius / jnp.maximum(gap, sensors.radius)


def refine_near_field(base, sensors: Sensors, near_by, light, near: int):
    """``base`` (charge, mean, variance) (N, C) of every disc with the ``near`` discs of
    largest ``near_by`` (``nearness``) blended into their sub-discs' light (``light``:
    ``disc_light_of``, on ``PANEL_BREAKS``) as their nearness rises from ``NEAR_FROM``
    to ``NEAR_FULL`` (``top_blend``). When every weight is 0 (no disc seen from the
    track's light at an angular radius above ``NEAR_FROM``: a track far from the walls)
    the sub-discs are not computed: the light and its derivatives are those of ``base``
    either way, since the blend's ramp starts flat (under ``vmap`` both are computed and
    one is kept)."""
    index, blend = top_blend(near_by, near, NEAR_FROM, NEAR_FULL - NEAR_FROM)

    def refined(base):
        offsets, scale = _sub_disc_offsets(sensors.normals[index], sensors.radius[index])
        subs = offsets.shape[1]
        sub = light((sensors.positions[index][:, None, :] + offsets).reshape(-1, 3),
                    jnp.repeat(sensors.normals[index], subs, axis=0),
                    jnp.repeat(sensors.radius[index] * scale, subs), breaks=PANEL_BREAKS)
        parts = [x.reshape(near, subs, -1) for x in sub]
        return blend_into(base, index, mixed_moments(*parts, axis=1), blend)

    return jax.lax.cond(jnp.any(blend > 0.0), refined, lambda base: base, base)


def blend_into(base, index, other, blend):
    """``base`` (charge, mean, variance) (N, C) with its rows ``index`` (K,) replaced by
    their mixture with ``other`` (charge, mean, variance) (K, C), of weight ``blend``
    (K,) in [0, 1], moment-matched per component; a row left without light keeps its
    mean."""
    charge, mean, variance = base
    weights = jnp.stack([1.0 - blend, blend], axis=1)[:, :, None]
    mixed = mixed_moments(jnp.stack([charge[index], other[0]], axis=1) * weights,
                          jnp.stack([mean[index], other[1]], axis=1),
                          jnp.stack([variance[index], other[2]], axis=1), axis=1)
    mean_near = where(mixed[0] > LIGHT_FLOOR, mixed[1], mean[index])
    return (charge.at[index].set(mixed[0]), mean.at[index].set(mean_near),
            variance.at[index].set(mixed[2]))


def top_blend(score, count: int, floor: float = 0.0, ramp: float = 0.0,
              relative_ramp: float = 0.0):
    """(indices (count,), blend weights in [0, 1]) of the ``count`` largest ``score``
    (dimensionless): a weight rises smoothly from 0 at ``low`` = max(``floor``, the
    next-largest score) to 1 at ``low`` + ``ramp`` + ``relative_ramp`` x ``low`` (so an
    entry leaving the selection has weight 0: whatever it selects enters continuously)."""
    values, index = jax.lax.top_k(score, count + 1)
    low = jnp.maximum(floor, values[-1])
    return index[:-1], smoothstep((values[:-1] - low) / (ramp + relative_ramp * low))


#: Distances to a disc are softened by this share of its radius (no singularity where the
#: light passes through a disc; relative error ~(r / 4 b)^2 at b off it).
SOFTENING = 0.25


def beside_track(positions, radius, position, direction):
    """(along, across) (N,) m of discs (centres (N, 3) m, radii (N,) m) from a track's
    start ``position`` (3,) m along its unit ``direction`` and across it, ``across``
    softened by ``SOFTENING`` x r."""
    offset = positions - position
    along = offset @ direction
    across2 = jnp.maximum(jnp.sum(offset * offset, axis=-1) - along * along, 0.0)
    return along, jnp.sqrt(across2 + (SOFTENING * radius) ** 2)


def seen_disc(to_sensor, normals, radius, params):
    """How discs see light from points: for vectors ``to_sensor`` (..., 3) m from the
    points to the disc centres, the discs' inward ``normals`` (..., 3) and radii
    ``radius`` (...) m, (length, cos_in, reach, share): the distance softened by r/4 (m),
    the cosine of incidence, sqrt(length^2 + r^2) (m), and the disc's solid angle over
    2 pi (0 from behind) x QE x angular acceptance x attenuation (dimensionless)."""
    length = jnp.sqrt(jnp.sum(to_sensor * to_sensor, axis=-1) + (SOFTENING * radius) ** 2)
    cos_in = -jnp.sum(to_sensor * normals, axis=-1) / length
    radius2 = radius * radius
    reach = jnp.sqrt(length * length + radius2)
    share = (jnp.maximum(cos_in, 0.0) * radius2 / (reach * (reach + length))
             * params.quantum_efficiency
             * acceptance_at_cos(params.angular_acceptance, cos_in)
             * jnp.exp(-interaction_rates(params)[3] * length))
    return length, cos_in, reach, share


def footprint_width(radius, reach, u, cos_in, facing):
    """Half-width in cos of a disc's footprint (a semicircle): sin(theta) x the disc's
    angular half-size along theta, for a disc of ``radius`` m at ``reach`` m (``seen_disc``)
    seen under cos ``u`` to the track, with cosine of incidence ``cos_in`` and ``facing``
    = track direction . disc normal."""
    sin2 = jnp.maximum(1.0 - u * u, 0.0)
    return radius / reach * safe_sqrt(sin2 - (u * cos_in + facing) ** 2)


def _sub_disc_offsets(normals, radius):
    """Centres of the equal-area sub-discs of each disc ((K, S, 3) offsets m from its
    centre, in its plane) and the sub-discs' radius over the disc's: a centre sub-disc
    and rings of 6, 12, ... (``SUB_DISC_RINGS`` rings)."""
    count = 1 + 3 * SUB_DISC_RINGS * (SUB_DISC_RINGS + 1)
    radii, angles = [0.0], [0.0]
    inner = 1.0
    for ring in range(1, SUB_DISC_RINGS + 1):
        outer = inner + 6 * ring
        radii += [math.sqrt(0.5 * (inner + outer) / count)] * (6 * ring)
        angles += [2 * math.pi * (k + 0.5 * (ring % 2)) / (6 * ring) for k in range(6 * ring)]
        inner = outer
    dtype = normals.dtype
    first, second = orthonormal_basis(normals)
    radii = jnp.asarray(radii, dtype)[None, :, None] * radius[:, None, None]
    angles = jnp.asarray(angles, dtype)[None, :, None]
    offsets = radii * (jnp.cos(angles) * first[:, None] + jnp.sin(angles) * second[:, None])
    return offsets, 1.0 / math.sqrt(count)


#: A mixture with less light than this (p.e.) gets mean 0 and variance 0: its moments'
#: derivatives, ~(time / light)^2, would overflow float32 (a run of the quadrature's
#: panels far from the Cherenkov peak can hold 1e-19 p.e.); so little light weighs
#: nothing in any likelihood.
LIGHT_FLOOR = 1e-12


def _stretch_knots(emission) -> np.ndarray:
    """(C - 1,) indices of the model's knots at equal shares of their count."""
    knots = emission.fraction.shape[0]
    return np.arange(1, DIRECT_COMPONENTS) * knots // DIRECT_COMPONENTS


def _stretch_cuts(emission, extent):
    """(C - 1,) distances (m) along the track that cut its light into the
    ``DIRECT_COMPONENTS`` stretches of the direct light's arrival-time components: the
    knots of ``_stretch_knots``, scaled into ``extent`` (m) where the wall ends the
    light before the model does (a track crossing a small detector gets all C
    components, not the one or two stretches of the model's first metres)."""
    return emission.fraction[_stretch_knots(emission)] * jnp.minimum(emission.extent, extent)


def mixed_moments(charge, mean, variance, axis):
    """Moments of the mixture of components (charge, mean, variance) along ``axis``:
    (charge summed, light-weighted mean, variance about it); a mixture with less light
    than ``LIGHT_FLOOR`` gets mean 0 and variance 0."""
    total = jnp.sum(charge, axis=axis)
    lit = total > LIGHT_FLOOR
    safe = where(lit, total, 1.0)
    first = jnp.sum(charge * mean, axis=axis) / safe
    second = jnp.sum(charge * (variance + mean * mean), axis=axis) / safe
    return total, where(lit, first, 0.0), where(lit, jnp.maximum(second - first * first, 0.0),
                                                 0.0)


def _disc_light(positions, normals, radius, *, params, position, direction, time, emission,
                extent, breaks):
    """``track_direct_light`` of the discs (centres (N, 3) m, inward normals (N, 3), radii
    (N,) m) without the near-field refinement, on panels ending at the cosines
    ``breaks`` (P,) (``PANEL_BREAKS``, or ``_peak_breaks``), clipped to each sensor's
    range, and at those of the model's knots."""
    dtype = positions.dtype
    along, across = beside_track(positions, radius, position, direction)
    u_start = _seen_cos(along, across)
    u_end = _seen_cos(along - extent, across)
    # panel ends: the fixed breaks (clipped to the sensor's range) and the cosines under
    # which the sensor sees the model's knots along the track, sorted per sensor
    fixed = jnp.clip(jnp.asarray(breaks, dtype)[None, :], u_end[:, None],
                     u_start[:, None])
    # the cuts between the components' stretches take the place of the knots they are
    # (the same where the model's light ends inside the detector; where the wall ends
    # it, a panel may straddle those three knots: TAO's crossing muon's first-hit PIT
    # was the same as with both as panel ends, which cost 14 % more)
    cuts = _stretch_cuts(emission, extent)  # (C - 1,) m
    knots_s = jnp.minimum(emission.fraction * emission.extent, extent)  # (D,)
    knots_s = knots_s.at[_stretch_knots(emission)].set(cuts)
    seen = _seen_cos(along[:, None] - knots_s[None, :], across[:, None])
    ends = jnp.sort(jnp.concatenate([fixed, seen], axis=1), axis=1)  # (N, P + D + ...)
    low, high = ends[:, :-1], ends[:, 1:]
    unit_nodes, unit_weights = (jnp.asarray(x, dtype) for x in _panel_rule())
    width = (high - low)[:, :, None]
    u = (low[:, :, None] + width * unit_nodes).reshape(low.shape[0], -1)  # (N, M)
    weight = (width * unit_weights).reshape(u.shape)

    sin2 = jnp.maximum(1.0 - u * u, jnp.finfo(dtype).tiny)
    sine = jnp.sqrt(sin2)
    across_ = across[:, None]
    s = jnp.clip(along[:, None] - across_ * u / sine, 0.0, extent)
    jacobian = across_ / (sin2 * sine)
    emitted = position + s[..., None] * direction  # (N, M, 3)
    to_sensor = positions[:, None, :] - emitted
    length, cos_in, reach, share = seen_disc(to_sensor, normals[:, None, :],
                                             radius[:, None], params)
    # the disc spans a range of cos around u: average the density over its footprint
    width = footprint_width(radius[:, None], reach, u, cos_in,
                            (direction @ normals.T)[:, None])
    light = weight * emission.density(s, u, width=width) * jacobian * share
    light = where(cos_in > 0.0, light, 0.0)
    offset_mean, offset_variance = emission.time_moments(s)
    reference = time + travel_time(jnp.linalg.norm(positions - position, axis=-1), params)
    arrival = time + s / SPEED_OF_LIGHT + offset_mean + travel_time(length, params) \
        - reference[:, None]
    # moment-matched components: the light of DIRECT_COMPONENTS stretches of the light's
    # visible part (no panel straddles a cut, so a node never changes stretch while its
    # panel has light)
    stretch = jnp.sum(s[..., None] > cuts, axis=-1)  # (N, M)
    member = stretch[..., None] == jnp.arange(DIRECT_COMPONENTS)  # (N, M, C)
    charge, mean, variance = mixed_moments(  # (N, C) each; the other nodes weigh 0
        where(member, light[..., None], 0.0), arrival[..., None],
        jnp.broadcast_to(offset_variance, light.shape)[..., None], axis=1)
    return charge, reference[:, None] + mean, variance
