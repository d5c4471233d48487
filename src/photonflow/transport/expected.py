"""Expected mode: the smooth prediction (direct light by quadrature + indirect by rays),
then the sensor response.

The transport (``sensor_light``) gives, per sensor j, the light of ``direct_light`` and
the indirect light of ``indirect_light`` by bounce order, as a Gaussian mixture of
K = 1 + n_bounces arrival-time components:

- component 0, direct light: mean = its straight-line arrival time, variance =
  pulse_width^2;
- component k (1..n_bounces), light whose last vertex is the k-th: mean and variance
  moment-matched to the charge-weighted arrival times of that light, plus
  pulse_width^2;

with weights proportional to each part's expected p.e. A sensor without light of some
order gets a zero weight for it (mean: the direct time, variance as for direct light);
a sensor with no light at all gets all weight on component 0 (finite and harmless).
The sensor response (``response.expected_response``) then scales the charge by the
sensor's efficiency, shifts the means by its time offset and adds tts^2 to every
variance.
"""

from __future__ import annotations

import functools
from weakref import WeakKeyDictionary

import jax
import jax.numpy as jnp
import numpy as np

from ..emission import emission_model, scintillation_emission
from ..emission.models import cherenkov_spectral_factor, scintillation_spectral_factor
from ..errors import ConfigError, format_value
from ..generator import Track
from ..geometry.detector import Detector
from ..geometry.sensor_arrays import Sensors, sensors_for
from ..geometry.sensor_grid import SensorGrid
from ..inline_jit import inline_jit
from ..numerics import default_float_dtype, strict_array, where
from ..params import Params, validate_params
from ..prediction import Prediction
from ..response.expected import SensorLight, expected_response
from ..sources import check_source
from .direct import direct_light_jit
from .indirect import indirect_light_jit
from .optics import TransportConfig, check_config
from .track_expected import hold_indirect, track_expected_jit
from .tracks import check_track, detector_medium, principal_sensor_model


def expected(
    detector: Detector,
    params: Params,
    source,
    *,
    config: TransportConfig | None = None,
    key=None,
    grid: SensorGrid | None = None,
    reference: Track | None = None,
) -> Prediction:
    """Expected p.e. and arrival-time mixture per sensor from a point source or a track.

    Works as JAX users write it: ``jax.jit(lambda p: expected(detector, p, source))``,
    ``jax.grad`` of a loss built on it, ``jax.vmap`` over a batch of sources (a source
    whose leaves have a leading axis). The detector's arrays and lookup grids are
    prepared once per detector, dtype and config (``expected_function``) and reused,
    so a second call, traced or not, does not recompile.

    Args:
        detector: sensors (positions m, inward normals, radii m) and boundary.
        params: detector parameters (lengths m, offsets and tts ns); its float dtype
            sets the computation's dtype.
        source: an ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource`` (position
            m, time and pulse width ns), or a ``Track`` (``docs/tracks.md``).
        config: static settings: ``n_bounces`` (vertices followed), ``n_rays`` (rays of
            the indirect light), Rayleigh anisotropy (default ``TransportConfig()``).
            Changing it recompiles.
        key: ``jax.random`` key fixing the rays' random numbers (default
            ``jax.random.key(0)``); the same key gives the same, smooth result.
        grid: sensor lookup grid (default: built once per detector object).
        reference: for a ``Track``, the track whose rays carry the indirect light
            (``transport/track_rays.py``): their geometry is fixed by it and the track
            enters through their weights, so the prediction is smooth in the track
            near the reference (within ~0.25 m and a few degrees). None: the track
            itself, held fixed (the value is the track's own; the gradient is that of
            the frozen rays).

    Returns:
        ``Prediction`` with ``charge`` (N,) p.e., a (N, 1 + n_bounces) time mixture in ns
        and ``residual_weight`` (photons still alive at the bounce cap). Differentiable
        in every field of ``params`` and ``source``; new values never recompile.

    Raises:
        ConfigError: concrete (not traced) ``params`` or ``source`` out of their domain,
            e.g. a source outside the detector, n_photons <= 0 or a NaN position (the
            same checks as ``sample``). Traced values are not checked: inside ``jit``
            a bad value gives a meaningless (possibly NaN) prediction, as any JAX
            function would.
    """
    config = TransportConfig() if config is None else config
    if is_concrete(params):
        validate_params(params, detector.n_sensors)
    if is_concrete(source):
        if isinstance(source, Track):
            check_expected_track(source, detector)
        else:
            check_source(source, detector)
    if reference is not None and is_concrete(reference):
        if not isinstance(reference, Track) or reference.particle != getattr(
                source, "particle", None):
            raise ConfigError(f"reference = {format_value(reference)}: must be a Track of the"
                              " source's particle")
        check_expected_track(reference, detector)
    dtype = jnp.result_type(params.absorption_length)
    predict = expected_function(detector, dtype, config=config, grid=grid)
    return predict(params, source, key, reference)


def check_expected_track(track: Track, detector: Detector) -> Track:
    """Raise a one-line ``ConfigError`` for a track outside the detector
    (``check_track``) or with an energy beyond its emission model's tables."""
    check_track(track, detector)
    top = emission_model(track.particle, detector_medium(detector)).energy_range[1]
    energy = float(np.max(np.asarray(track.energy)))  # numpy: not traced inside jit
    if energy > top * (1.0 + 1e-6):  # the top node, read back from float32, included
        raise ConfigError(f"track.energy = {format_value(energy)} MeV: beyond the emission"
                          f" tables of {track.particle} (up to {top:g} MeV)")
    return track


def is_concrete(tree) -> bool:
    """True when no leaf of ``tree`` is a JAX tracer (its values can be checked)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


def expected_function(
    detector: Detector,
    dtype=None,
    *,
    config: TransportConfig | None = None,
    grid: SensorGrid | None = None,
):
    """The prepared predictor: a function ``predict(params, source, key=None,
    reference=None, *, emission=None, arrays=None, held=None) -> Prediction``
    (``reference``: see ``expected``; ``emission``, ``arrays``: the emission model and
    the ``Sensors`` to use instead of the ones closed over, to pass them as arguments of
    a jitted caller; ``held``: for a track, the indirect light of a nearby track from
    ``held_indirect_function``, used instead of tracing rays) with the detector's arrays
    and grids built once and closed over.

    ``expected`` calls it (and checks concrete inputs first); use it directly in code
    that calls the prediction many times outside ``jit`` with values known to be good
    (no checks, no cache lookup), or to hand a plain function of (params, source, key)
    to ``jit``, ``grad``, ``vmap`` or an optimiser. Without ``grid`` the predictor is
    cached per detector object, dtype and config.

    Args:
        detector: sensors (positions m, normals, radii m) and boundary.
        dtype: float dtype of the computation (default JAX's default float); ``params``
            and ``source`` are cast to it.
        config: static transport settings (default ``TransportConfig()``).
        grid: sensor lookup grid (default: built once per detector object).
    """
    return _functions(detector, dtype, config, grid)[0]


def held_indirect_function(
    detector: Detector,
    dtype=None,
    *,
    config: TransportConfig | None = None,
    grid: SensorGrid | None = None,
):
    """The indirect light of a track to hold while it moves: a function ``hold(params,
    track, key=None, *, emission=None, arrays=None, slopes=True)`` giving a tuple of
    ``track_expected.HeldIndirect`` (one per emission part: Cherenkov, then
    scintillation where the medium has it), computed by the track's own rays with its
    first derivatives in the track (``slopes`` False: without them, ~10x faster), for
    ``expected_function``'s ``held``. A prediction that holds it costs the direct
    light's quadrature alone (a fit's stages hold it and refresh it as the track
    moves: ``photonflow.reconstruct``). Arguments as ``expected_function``'s; lengths m,
    times ns, charges p.e."""
    return _functions(detector, dtype, config, grid)[1]


def _functions(detector: Detector, dtype, config, grid) -> tuple:
    """(predict, hold) of ``expected_function`` and ``held_indirect_function``, cached
    per detector object, dtype and config without ``grid``."""
    config = check_config(TransportConfig() if config is None else config)
    dtype = default_float_dtype() if dtype is None else jnp.dtype(dtype)
    if grid is not None:
        return _predictor(detector, dtype, config, grid)
    cached = _PREDICTORS.setdefault(detector, {})
    if (dtype, config) not in cached:
        cached[(dtype, config)] = _predictor(detector, dtype, config, None)
    return cached[(dtype, config)]


def _predictor(detector: Detector, dtype, config: TransportConfig, grid):
    """(predict, hold): ``expected_function``'s predictor and ``held_indirect_function``'s
    function, uncached."""
    cast = functools.partial(strict_array, dtype=dtype)
    sensors = sensors_for(detector, dtype, grid)
    medium = detector_medium(detector)

    @functools.cache
    def spectral() -> tuple[float, float]:  # only tracks need it (and a known sensor model)
        sensor = principal_sensor_model(detector)
        return (cherenkov_spectral_factor(sensor, medium),
                scintillation_spectral_factor(sensor, medium))

    def track_inputs(track, emission) -> tuple:
        """(model, its spectral factor, scintillation) of a ``Track``'s light."""
        model = (emission_model(track.particle, medium, dtype, config.emission_model)
                 if emission is None else emission)
        scintillator = scintillation_emission(track.particle, medium, dtype)
        cherenkov_factor, scintillation_factor = spectral()
        scintillation = None if scintillator is None else (scintillator,
                                                           cast(scintillation_factor))
        return model, cast(cherenkov_factor), scintillation

    def predict(params: Params, source, key=None, reference=None, *, emission=None,
                arrays: Sensors | None = None, held=None) -> Prediction:
        """Expected p.e. and time mixture per sensor (see ``expected``); no checks.
        ``emission`` (a track's emission model, default the shipped one of its
        particle, ``emission.emission_model``) and ``arrays`` (the detector's
        ``Sensors``, default ``sensors_for(detector, dtype)``) may be passed in:
        a function that jits a predictor call and takes them as its arguments keeps
        them out of its compiled program, whose constants they would otherwise be
        (an SK spline table is 21 MB, the SK sensors 19 MB). ``held``: a track's held
        indirect light (``held_indirect_function``), or None."""
        sensors_used = sensors if arrays is None else arrays
        if isinstance(source, Track):
            model, factor, scintillation = track_inputs(source, emission)
            if reference is not None:
                reference = jax.tree.map(cast, reference)
            return track_expected_jit(
                sensors_used, jax.tree.map(cast, params), jax.tree.map(cast, source), model,
                factor, key, reference, scintillation, held, shape=detector.shape,
                config=config,
            )
        if reference is not None or held is not None:
            name = "reference" if reference is not None else "held"
            raise ConfigError(f"{name}: only a Track source takes it (source:"
                              f" {type(source).__name__})")
        return expected_jit(
            sensors_used, jax.tree.map(cast, params), jax.tree.map(cast, source), key,
            shape=detector.shape, config=config,
        )

    def hold(params: Params, track: Track, key=None, *, emission=None,
             arrays: Sensors | None = None, slopes: bool = True) -> tuple:
        """The held indirect light of ``track`` (``held_indirect_function``)."""
        model, factor, scintillation = track_inputs(track, emission)
        return hold_indirect(sensors if arrays is None else arrays,
                             jax.tree.map(cast, params), jax.tree.map(cast, track), model,
                             factor, key, scintillation, shape=detector.shape,
                             config=config, slopes=slopes)

    return predict, hold


#: Prepared predictors per detector object (weak: a pure cache), keyed by (dtype, config).
_PREDICTORS: WeakKeyDictionary = WeakKeyDictionary()


@inline_jit(static_argnames=("shape", "config"))
def expected_jit(sensors: Sensors, params, source, key=None, mirror=None, *, shape, config):
    """``expected`` on arrays: the detector's ``Sensors``, ``params`` and ``source`` of
    one float dtype, a ``jax.random`` key (None: ``jax.random.key(0)``) and the source's
    first-order mirror paths (``mirror.mirror_paths``; None: computed here); ``shape``
    and ``config`` static. The transport (``sensor_light``) followed by the sensor
    response (``response.expected_response``). Returns a ``Prediction``."""
    light = sensor_light(sensors, params, source, key, mirror, shape=shape, config=config)
    return expected_response(light, params)


def sensor_light(sensors: Sensors, params, source, key=None, mirror=None, *, shape, config):
    """The expected mode's transport: the ``SensorLight`` arriving at each sensor (p.e. of
    a sensor of relative efficiency 1, times before its offset and transit-time spread),
    from direct light and the indirect light of each bounce order (the module
    docstring's mixture); arguments as ``expected_jit``'s. Traced inline (call it inside
    a jitted function)."""
    key = jax.random.key(0) if key is None else key  # in the trace: no eager program
    mu_direct, t_direct = direct_light_jit(sensors, params, source)
    indirect = indirect_light_jit(
        sensors, params, source, t_direct, key, mirror, shape=shape, config=config
    )
    charge = jnp.concatenate([mu_direct[None], indirect.charge], axis=0).T  # (N, K)
    means = jnp.concatenate([t_direct[None], indirect.time_mean], axis=0).T
    variances = jnp.concatenate(
        [jnp.zeros_like(t_direct)[None], indirect.time_variance], axis=0
    ).T
    has_light = charge > 0
    pulse = source.pulse_width * source.pulse_width
    return SensorLight(
        charge=charge,
        time_mean=where(has_light, means, t_direct[:, None]),
        time_variance=where(has_light, variances, 0.0) + pulse,
        residual_weight=indirect.residual_weight,
        window=tuple(float(x) for x in config.window),
    )
