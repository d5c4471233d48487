"""Expected mode for particle tracks: the light of a ``Track`` at every sensor, then the
sensor response.

The track's energy selects its emission model (``photonflow.emission``: the shipped
spline model of its particle in the detector's medium); the direct light comes by
quadrature in the angle to the track (``track_direct``), the indirect light (scattered
and reflected, by bounce order) from the weighted rays of ``indirect.py`` leaving the
track (``track_rays.TrackEmitter``: their geometry fixed by a reference track, so the
indirect light is smooth in the track). The light is a mixture of C + 2 n_bounces
arrival-time components per sensor: C for the direct light
(``track_direct.DIRECT_COMPONENTS``, each moment-matched to the light of a stretch of
the track), then per kind of last vertex (bulk scatter, surface) one per bounce order,
exponentially modified (``_skewed_indirect``: scattered light starts no earlier than
direct light can arrive, and trails off); in a scintillator, its isotropic scintillation
light (``emission.ScintillationModel``) through the same quadrature and rays, each of its
components split into one exponentially modified component per decay time. The sensor
response (``response.expected_response``) then applies efficiencies, offsets and the
transit-time spread. Lengths m, times ns, energies MeV.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..constants import SPEED_OF_LIGHT
from ..emission import SplineEmission
from ..emission.moments import TabulatedSlice
from ..geometry.sensor_arrays import Sensors
from ..inline_jit import inline_jit
from ..numerics import safe_sqrt, where
from ..prediction import Prediction
from ..pytree import pytree_dataclass
from ..response.expected import SensorLight, expected_response
from .indirect import indirect_light_jit
from .track_direct import DIRECT_COMPONENTS, LIGHT_FLOOR, mixed_moments, track_direct_light
from .track_moments import tabulated_direct_light
from .track_rays import TrackEmitter, kernel_width


@pytree_dataclass
class HeldIndirect:
    """The indirect light of one emission part (the Cherenkov light, or the
    scintillation light) of a track, computed once at that track with its first
    derivatives and held while the track moves (``hold_indirect``; the fit stages of
    ``photonflow.reconstruct``).

    A prediction that takes it (``track_sensor_light``'s ``held``) uses its components
    instead of tracing rays, to first order in the track's move z = (position - held
    position, direction - held direction, log(energy / held energy)):
    charge = charge_0 x (direct light / direct_total) x exp(charge_slope . z) (the
    light emitted inside the detector follows the direct light; the slopes are those
    of the indirect light's share of it), means + (time - held time) + mean_slope . z,
    variances + variance_slope . z (kept >= 0). At the held track its value and
    gradient are the full prediction's with the rays fixed there (``expected``'s
    ``reference``); away from it, the error is of second order in z (the indirect
    light is smooth over metres and tens of degrees).

    Attributes:
        charge: (N, 2 n_bounces) p.e. of sensors of efficiency 1, by the kind of the
            last vertex (bulk scatter, surface) and its order.
        time_mean: (N, 2 n_bounces) mean arrival times, ns. time_variance: ns^2.
        charge_slope: (N, 2 n_bounces, 7) d log(charge / direct_total) / dz (per m,
            per unit of the direction's components, per unit of log energy).
        mean_slope: (N, 2 n_bounces, 7) d time_mean / dz, ns per unit of z.
        variance_slope: (N, 2 n_bounces, 7) d time_variance / dz, ns^2 per unit of z.
        residual_weight: photons still alive at the bounce cap.
        direct_total: the direct light's total over the sensors at the held track, p.e.
        position: (3,) m, direction: (3,) unit, log_energy: log(MeV), time: ns: the
            held track.
    """

    charge: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    charge_slope: jax.Array
    mean_slope: jax.Array
    variance_slope: jax.Array
    residual_weight: jax.Array
    direct_total: jax.Array
    position: jax.Array
    direction: jax.Array
    log_energy: jax.Array
    time: jax.Array

    def move(self, track, direction, direct_total) -> tuple:
        """([charge, mean, variance] (N, 2 n_bounces), residual weight) of the held
        light for ``track`` (unit ``direction``; its direct light's total
        ``direct_total`` p.e.)."""
        z = jnp.concatenate([track.position - self.position, direction - self.direction,
                             jnp.log(track.energy)[None] - self.log_energy])
        positive = self.direct_total > 0
        scale = where(positive, direct_total / where(positive, self.direct_total, 1.0), 1.0)
        # the exponent bounded smoothly (a move far beyond the linear range, early in a
        # fit, cannot overflow)
        exponent = HELD_EXPONENT * jnp.tanh(self.charge_slope @ z / HELD_EXPONENT)
        return [self.charge * scale * jnp.exp(exponent),
                self.time_mean + (track.time - self.time) + self.mean_slope @ z,
                jnp.maximum(self.time_variance + self.variance_slope @ z, 0.0)], \
            self.residual_weight * scale


#: Bound of the held charge's exponent (``HeldIndirect.move``): a factor of e^2 at most.
HELD_EXPONENT = 2.0


def track_sensor_light(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, reference=None, scintillation=None, held=None, *, shape,
                       config):
    """The ``SensorLight`` of one track (a ``Track`` of one particle, leaves of the
    computation's dtype): (N, C + 2 n_bounces) p.e. of sensors of efficiency 1 (C direct
    components, ``track_direct.DIRECT_COMPONENTS``, then by the kind of the last vertex
    (bulk scatter, surface) and its order, the indirect ones with exponential tails:
    ``_skewed_indirect``), with mean arrival times, variances and decay times (ns, ns^2,
    ns). ``spectral``: the sensor's mean relative spectral response over the emitted
    spectrum (``cherenkov_spectral_factor``), which scales the QE at the reference wavelength;
    ``key`` fixes the rays (None: ``jax.random.key(0)``); ``shape`` and ``config``
    static; ``reference``: the track that fixes the indirect light's rays
    (``track_rays``; None: the track itself, held fixed). ``scintillation``: None, or
    (the medium's ``ScintillationModel``, its ``scintillation_spectral_factor``): the
    isotropic scintillation light is added as ``SCINTILLATION_COMPONENTS`` x (number of
    decay times) exponentially modified components (``time_tau``). ``held``: None, or
    the ``hold_indirect`` of a nearby track (a tuple of ``HeldIndirect``, one per
    emission part), used instead of the rays (``reference`` and ``key`` then unused).
    Traced inline."""
    direction = track.direction / jnp.linalg.norm(track.direction)
    length = _inside_length(shape, track.position, direction)
    parts = _part_light(sensors, params, track, direction, length, model, spectral, key,
                        reference, scintillation, held, shape=shape, config=config)
    charges, means, variances, residual, start = parts[0]
    onset = earliest_arrival(sensors, params, track.position, direction, track.time, length)
    charges, means, variances, tau = _skewed_indirect(charges, means, variances, onset)
    if scintillation is not None:
        scintillator = scintillation[0]
        delayed = _decayed(*parts[1][:3], onset, scintillator.decay_times,
                           scintillator.decay_weights)
        tau = jnp.concatenate([tau, delayed[3]], axis=1)
        charges, means, variances = (jnp.concatenate([a, b], axis=1) for a, b in
                                     zip((charges, means, variances), delayed[:3],
                                         strict=True))
        residual = residual + parts[1][3]
    has_light = charges > LIGHT_FLOOR
    return SensorLight(
        charge=charges,
        time_mean=where(has_light, means, start[:, None]),
        time_variance=where(has_light, variances, 0.0),
        residual_weight=residual,
        window=tuple(float(x) for x in config.window),
        time_tau=tau,
    )


@inline_jit(static_argnames=("shape", "config", "slopes"))
def hold_indirect(sensors: Sensors, params, track, model: SplineEmission, spectral,
                  key=None, scintillation=None, *, shape, config, slopes: bool = True
                  ) -> tuple:
    """The indirect light of ``track`` by its own rays and its first derivatives
    (forward mode, 7 directions; ``slopes`` False: zero, at ~1/10 of the cost), to hold
    (``HeldIndirect``, one per emission part: the Cherenkov light, then the
    scintillation light where ``scintillation`` is given); other arguments as
    ``track_sensor_light``'s."""
    indirect = slice(DIRECT_COMPONENTS, None)
    fixed = jax.tree.map(jax.lax.stop_gradient, track)
    direction = fixed.direction / jnp.linalg.norm(fixed.direction)

    def slices_at(energy):  # the rays' slices stay at the held track's energy
        return _slices(model, scintillation, energy, fixed.energy)

    def light(z, slices):
        moved = fixed.replace(position=fixed.position + z[:3], direction=direction + z[3:6],
                              energy=fixed.energy * jnp.exp(z[6]))
        unit = moved.direction / jnp.linalg.norm(moved.direction)
        length = _inside_length(shape, moved.position, unit)
        parts = _part_light(sensors, params, moved, unit, length, model, spectral, key,
                            fixed, scintillation, None, slices, shape=shape, config=config)
        out = []
        for charges, means, variances, residual, _ in parts:
            total = jnp.sum(charges[:, :DIRECT_COMPONENTS])
            share = charges[:, indirect] / where(total > 0, total, 1.0)
            out.append((share, means[:, indirect], charges[:, indirect], variances[:, indirect],
                        residual, total))
        return out

    zero = jnp.zeros(7, direction.dtype)
    held_slices = _slices(model, scintillation, fixed.energy)  # one slice serves both
    if slopes:
        # the 6 geometric directions with the emission model's slices held (no tangent
        # through their tables), then the energy's (through the slices) by one jvp
        def geometric(z6):
            out = light(jnp.concatenate([z6, zero[:1]]), held_slices)
            return out, out

        shape_slopes, values = jax.jacfwd(geometric, has_aux=True)(zero[:6])
        _, energy_slopes = jax.jvp(
            lambda e: light(zero.at[6].set(e), slices_at(fixed.energy * jnp.exp(e))),
            (zero[6],), (jnp.ones_like(zero[6]),))
        derivatives = jax.tree.map(lambda a, b: jnp.concatenate([a, b[..., None]], axis=-1),
                                   shape_slopes, energy_slopes)
    else:
        values = light(zero, held_slices)
        derivatives = jax.tree.map(lambda x: jnp.zeros(x.shape + (7,), x.dtype), values)
    held = []
    for slope, value in zip(derivatives, values, strict=True):
        share_slope, mean_slope, _, variance_slope, *_ = slope
        share, mean, charge, variance, residual, total = value
        lit = share > 0
        held.append(HeldIndirect(
            charge=charge, time_mean=mean, time_variance=variance,
            charge_slope=where(lit[..., None], share_slope / where(lit, share, 1.0)[..., None],
                               0.0),
            mean_slope=where(lit[..., None], mean_slope, 0.0),
            variance_slope=where(lit[..., None], variance_slope, 0.0),
            residual_weight=residual, direct_total=total, position=fixed.position,
            direction=direction, log_energy=jnp.log(fixed.energy)[None],
            time=jnp.asarray(fixed.time, charge.dtype)))
    return tuple(held)


def _part_light(sensors, params, track, direction, length, model, spectral, key, reference,
                scintillation, held, slices=None, *, shape, config) -> list:
    """``_emitted_light`` of each emission part of the track: its Cherenkov light, then,
    with ``scintillation``, its scintillation light (its own key); ``held``: None, or
    one ``HeldIndirect`` per part; ``slices``: None, or each part's (slice at the
    track's energy, slice at the reference's) from ``_slices``."""
    key = jax.random.key(0) if key is None else key
    rays_from = jax.tree.map(jax.lax.stop_gradient, track if reference is None else reference)
    if slices is None:
        slices = _slices(model, scintillation, track.energy,
                         None if reference is None else rays_from.energy)
    factors = [spectral] + ([] if scintillation is None else [scintillation[1]])
    keys = [key, jax.random.fold_in(key, 1)]
    return [_emitted_light(
        sensors, params.replace(quantum_efficiency=params.quantum_efficiency * factor),
        track, direction, length, light, rays_light, rays_from, part_key,
        None if held is None else held[k], shape=shape, config=config)
        for k, ((light, rays_light), factor, part_key)
        in enumerate(zip(slices, factors, keys[:len(slices)], strict=True))]


def _slices(model, scintillation, energy, rays_energy=None) -> list:
    """Per emission part (the Cherenkov ``model``, then the scintillation model where
    ``scintillation`` is given), its (slice at ``energy``, slice at ``rays_energy``:
    the same where None), MeV."""
    models = [model] + ([] if scintillation is None else [scintillation[0]])
    pairs = []
    for light_model in models:
        light = light_model.at(energy)
        pairs.append((light, light if rays_energy is None else light_model.at(rays_energy)))
    return pairs


#: Indirect components whose exponential delay would be below this (ns) stay Gaussian.
SHORTEST_TAIL = 0.1


def earliest_arrival(sensors: Sensors, params, position, direction, time, length):
    """(N,) the earliest time (ns) any light of the track can reach each sensor centre:
    min over the track's points s in [0, length] (m) of t0 + s / c + n_g |p - x(s)| / c,
    reached where the sensor is seen at cos = 1 / n_g from the track (light made later
    along the track, delayed at emission, or bent by a scatter or a reflection only
    comes later)."""
    offset = sensors.positions - position
    along = offset @ direction
    across = safe_sqrt(jnp.sum(offset * offset, axis=1) - along * along)
    n_g = params.group_index
    s = jnp.clip(along - across / safe_sqrt(n_g * n_g - 1.0), 0.0, length)
    return time + (s + n_g * safe_sqrt((along - s) ** 2 + across * across)) / SPEED_OF_LIGHT


def _skewed_indirect(charge, mean, variance, onset):
    """The indirect components (after the ``DIRECT_COMPONENTS``) as exponentially
    modified Gaussians with the skewness of a gamma distribution that starts at
    ``onset`` (N,) ns (``earliest_arrival``): scattered and reflected light cannot
    arrive before it, and a symmetric shape puts a share of the light there.

    A component of mean m and spread s, with d = m - onset, is the gamma distribution of
    that mean and variance starting at the onset (shape k = d^2 / s^2, skewness 2 s / d)
    matched in its first three moments: exponential delay tau = s (s / d)^(1/3),
    Gaussian variance s^2 - tau^2 and mean m - tau. A spread wider than d (k < 1, a
    shape falling from the onset) is an exponential from the onset, tau = d. Before the
    transit-time spread. Returns (charge, mean, variance, tau) (N, K)."""
    indirect = slice(DIRECT_COMPONENTS, None)
    spread = safe_sqrt(variance[:, indirect])
    delay = jnp.maximum(mean[:, indirect] - onset[:, None], SHORTEST_TAIL)
    narrow = spread < delay
    ratio = where(narrow & (spread > 0.0), spread / delay, 1.0)
    tau = where(narrow, spread * jnp.cbrt(ratio), delay)
    tail = tau > SHORTEST_TAIL
    tau = where(tail, tau, 0.0)
    mean = mean.at[:, indirect].add(-tau)
    gaussian = where(narrow, jnp.maximum(variance[:, indirect] - tau * tau, 0.0), 0.0)
    variance = variance.at[:, indirect].set(where(tail, gaussian, variance[:, indirect]))
    return charge, mean, variance, jnp.concatenate([jnp.zeros_like(mean[:, :DIRECT_COMPONENTS]),
                                                    tau], axis=1)


#: The scintillation light's indirect Gaussian lies this many of its spreads after the
#: onset (0.6 % of it before).
ONSET_SPREADS = 2.5
#: Transport components of the scintillation light before its decay delays: the direct
#: light's components merged in pairs, and its indirect light as one.
SCINTILLATION_COMPONENTS = DIRECT_COMPONENTS // 2 + 1


def _emitted_light(sensors, params, track, direction, length, emission, rays_emission,
                   rays_from, key, held=None, *, shape, config):
    """(charge, mean, variance) (N, C + 2 n_bounces) of the light of one emission slice
    (direct components, then by kind of last vertex and bounce order), the residual
    weight of its rays and the sensors' mean direct arrival time (N,) ns (the time of
    light from the track's start where there is no direct light). ``held``: None, or
    the part's ``HeldIndirect``, used instead of rays (its docstring)."""
    direct = (tabulated_direct_light if isinstance(emission, TabulatedSlice)
              else track_direct_light)
    charge, mean, variance = direct(sensors, params, track.position, direction, track.time,
                                    emission, length)
    total = jnp.sum(charge, axis=1)
    lit = total > LIGHT_FLOOR
    start = jnp.sum(charge * mean, axis=1) / where(lit, total, 1.0)
    start = where(lit, start, mean[:, 0])
    if held is None:
        emitter = TrackEmitter(track.position, direction, track.time, emission, length,
                               rays_from.position,
                               rays_from.direction / jnp.linalg.norm(rays_from.direction),
                               rays_emission, spread=kernel_width(shape))  # held fixed
        indirect = indirect_light_jit(sensors, params, emitter, start, key, shape=shape,
                                      config=config)
        # (N, 2 n_bounces): by the kind of the last vertex (bulk scatter, surface) and
        # its order
        by_kind = [x.reshape(-1, x.shape[-1]).T for x in
                   (indirect.kind_charge, indirect.kind_time_mean,
                    indirect.kind_time_variance)]
        residual = indirect.residual_weight
    else:
        by_kind, residual = held.move(track, direction, jnp.sum(total))
    charges, means, variances = (jnp.concatenate([a, b], axis=1) for a, b in
                                 zip((charge, mean, variance), by_kind, strict=True))
    return charges, means, variances, residual, start


def _decayed(charge, mean, variance, onset, decay_times, decay_weights):
    """The scintillation light's components (N, C + 2 n_bounces) merged into
    ``SCINTILLATION_COMPONENTS`` (moment-matched), each split into one exponentially
    modified component per decay time: (charge, mean, variance, tau) (N, 3 x ...). The
    indirect light's merged Gaussian is narrowed (its mean kept) to lie
    ``ONSET_SPREADS`` spreads after ``onset`` (N,) ns (``earliest_arrival``): scattered
    and reflected light cannot arrive before it, and the decay delays, not the
    Gaussian, carry most of the shape."""
    pairs = [mixed_moments(charge[:, k:k + 2], mean[:, k:k + 2], variance[:, k:k + 2], axis=1)
             for k in range(0, DIRECT_COMPONENTS, 2)]
    pairs.append(mixed_moments(charge[:, DIRECT_COMPONENTS:], mean[:, DIRECT_COMPONENTS:],
                        variance[:, DIRECT_COMPONENTS:], axis=1))
    merged = [jnp.stack(x, axis=1) for x in zip(*pairs, strict=True)]  # 3 x (N, S)
    lit = merged[0] > LIGHT_FLOOR
    merged[1] = where(lit, merged[1], mean[:, :1])
    delay = jnp.maximum(merged[1][:, -1] - onset, 0.0) / ONSET_SPREADS
    merged[2] = merged[2].at[:, -1].set(jnp.minimum(merged[2][:, -1], delay * delay))
    outputs = [[], [], [], []]
    for tau, weight in zip(decay_times, decay_weights, strict=True):
        outputs[0].append(weight * merged[0])
        outputs[1].append(merged[1])
        outputs[2].append(merged[2])
        outputs[3].append(jnp.full_like(merged[0], tau))
    return tuple(jnp.concatenate(x, axis=1) for x in outputs)


def _inside_length(shape, position, direction):
    """Distance (m) from the track's start to the wall along its direction (a large
    number in an open medium)."""
    if not shape.has_walls:
        return jnp.asarray(1e9, position.dtype)
    exit_distance = shape.ray_exit(position[None], direction[None])[0]
    return jnp.where(jnp.isfinite(exit_distance), jnp.maximum(exit_distance, 0.0), 1e9)


@inline_jit(static_argnames=("shape", "config"))
def track_expected_jit(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, reference=None, scintillation=None, held=None, *, shape,
                       config) -> Prediction:
    """``expected`` of one track on arrays (``track_sensor_light`` then the sensor
    response); ``shape`` and ``config`` static. Returns a ``Prediction``."""
    light = track_sensor_light(sensors, params, track, model, spectral, key, reference,
                               scintillation, held, shape=shape, config=config)
    return expected_response(light, params)
