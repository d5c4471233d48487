"""Optical processes shared by the expected and the sampled transport modes.

One description of the physics, used by both modes so that they agree by construction:

- bulk: absorption, Rayleigh scattering with the phase function 1 + a cos^2(theta)
  (a from the medium, water 0.835) and optional Mie scattering (Henyey-Greenstein, g);
- wall: a photon reaching the wall is reflected with probability
  ``wall_reflectivity``; a reflection is specular with probability
  ``wall_specular_fraction`` and Lambertian (cosine law) otherwise; the rest is absorbed;
- sensor: a photon crossing a sensor's disc from the front is reflected by its glass
  with probability ``sensor_reflectivity``; otherwise it is detected or absorbed, as
  the sensor response decides (``photonflow.response.detection``: detected with
  probability QE x efficiency_j x acceptance(incidence) per arriving photon; the
  expected mode weighs arriving light by QE x acceptance path by path and its response
  applies efficiency_j). The reflection is specular off
  the hemispherical glass dome above the disc: a photon crossing the disc at offset q
  from its centre is mirrored about the dome's normal there, (q + sqrt(r^2 - |q|^2) n)
  / r. A convex dome spreads the reflected light over a wide range of directions
  (``dome_reflection_density``), as the glass of a real PMT does; a flat mirror disc
  would not.

Samplers take uniform random numbers explicitly (reparameterised), so the expected mode
can fix them and stay smooth in the parameters. Angles in rad, lengths in m.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp

from ..constants import SPEED_OF_LIGHT
from ..errors import ConfigError, format_value
from ..geometry.sensor_arrays import WIDEST_DISC
from ..numerics import clip, where
from ..params import Params

#: Phase-function anisotropy a of Rayleigh scattering in water: (1 - d)/(1 + d) for
#: depolarisation d = 0.09 (Morel 1974; physics.md section 1).
WATER_RAYLEIGH_ANISOTROPY = 0.835


@dataclasses.dataclass(frozen=True)
class TransportConfig:
    """Static settings of light transport (hashable; changing them recompiles).

    Attributes:
        n_bounces: scattering/reflection vertices followed after emission (expected
            mode) or the cap on interactions per photon (sampled mode); photons still
            alive at the cap are counted as ``lost``.
        n_rays: rays per source for the indirect light of the expected mode.
        rayleigh_anisotropy: a in the Rayleigh phase function 1 + a cos^2.
        window: readout window (start, end) in ns relative to the source time.
        charge_threshold: hits below this charge (p.e.) are not recorded.
        batch_size: photons processed at once in sampled mode (bounds memory).
        mie_proposal_asymmetry: Henyey-Greenstein g of the fixed proposal from which
            the expected mode draws half of its scattered directions (the other half
            from the Rayleigh phase function). The proposal never depends on
            ``Params``, so the rays' paths do not move when a parameter changes and
            ``Params.mie_g`` enters only through the weights; a value near the medium's
            ``mie_g`` keeps the weights' variance low.
        specular_probes: probe rays per vertex and ray (and per ray at the source) that
            look for light mirrored by the wall into a sensor (``indirect.py``); the
            variance of that light falls as 1 / specular_probes.
        specular_smoothing: a vertex's probe counts on every sensor whose disc, widened
            by this factor in its own plane, the mirrored ray crosses, with weight
            1 / factor^2 (``specular_probes.specular_probes``): 1 is the physical disc
            (unbiased); 3.5 (default) lowers that light's variance several-fold for a
            bias of ~10^-4 of a sensor's light (``docs/transport.md``). Between 1 and
            ``sensor_arrays.WIDEST_DISC`` (3.5).
        emission_model: the emission model of particle tracks, "spline" (default),
            "siren", or "tables": the spline with moment tables from which the direct
            light of the sensors seen from afar is read, ~4x faster for that light
            (``photonflow.emission.emission_model``; ``docs/tracks.md`` compares
            them).
    """

    n_bounces: int = 2
    n_rays: int = 4096
    rayleigh_anisotropy: float = WATER_RAYLEIGH_ANISOTROPY
    window: tuple[float, float] = (-100.0, 900.0)
    charge_threshold: float = 0.0
    batch_size: int = 1 << 17
    mie_proposal_asymmetry: float = 0.4
    specular_probes: int = 12
    specular_smoothing: float = 3.5
    emission_model: str = "spline"


def check_config(config: TransportConfig) -> TransportConfig:
    """Raise a one-line ``ConfigError`` for an unusable ``TransportConfig``; return it."""

    def bad(name, value, rule):
        return ConfigError(f"config.{name} = {format_value(value)}: {rule}")

    for name, minimum in (("n_bounces", 0), ("batch_size", 1), ("n_rays", 1),
                          ("specular_probes", 1)):
        value = getattr(config, name)
        if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
            raise bad(name, value, f"must be an integer >= {minimum}")
    smoothing = float(config.specular_smoothing)
    if not 1.0 <= smoothing <= WIDEST_DISC:
        raise bad("specular_smoothing", config.specular_smoothing,
                  f"must be between 1 and {WIDEST_DISC:g} (disc radii)")
    start, end = (float(x) for x in config.window)
    if not (math.isfinite(start) and math.isfinite(end) and start < end):
        raise bad("window", config.window, "must be finite (start, end) ns with start < end")
    for name in ("charge_threshold", "rayleigh_anisotropy"):
        if not math.isfinite(float(getattr(config, name))):
            raise bad(name, getattr(config, name), "must be finite")
    return config


#: The default ``TransportConfig`` (readout window -100..900 ns, no threshold).
DEFAULT_CONFIG = TransportConfig()


def interaction_rates(params: Params):
    """Bulk rates (1/m): (absorption, Rayleigh, Mie, total). ``inf`` lengths give 0."""
    absorption = 1.0 / params.absorption_length
    rayleigh = 1.0 / params.scattering_length
    mie = 1.0 / params.mie_length
    return absorption, rayleigh, mie, absorption + rayleigh + mie


def rayleigh_density(cos_theta, anisotropy):
    """Rayleigh phase function per steradian: (1 + a cos^2) / (4 pi (1 + a / 3))."""
    return (1.0 + anisotropy * cos_theta**2) / (4.0 * math.pi * (1.0 + anisotropy / 3.0))


def sample_rayleigh_cos(u, anisotropy, iterations: int = 12):
    """cos(theta) of Rayleigh scattering from a uniform u in (0, 1) (inverse CDF).

    The CDF (mu + 1 + a (mu^3 + 1) / 3) / (2 (1 + a / 3)) is inverted by Newton steps
    from mu = 2u - 1 (the CDF is monotonic; 12 steps reach float64 precision for
    a <= 1); differentiable in u and a.
    """
    target = 2.0 * (1.0 + anisotropy / 3.0) * u - 1.0 - anisotropy / 3.0  # g(mu) = target

    def newton(_, mu):
        value = mu + anisotropy * mu**3 / 3.0 - target
        slope = 1.0 + anisotropy * mu**2
        return clip(mu - value / slope, -1.0, 1.0)

    return jax.lax.fori_loop(0, iterations, newton, 2.0 * u - 1.0)


def henyey_greenstein_density(cos_theta, g):
    """Henyey-Greenstein phase function per steradian with asymmetry g in (-1, 1)."""
    base = 1.0 + g * g - 2.0 * g * cos_theta
    denominator = base * jnp.sqrt(base)  # base^1.5 without a pow (cheap per pair)
    return (1.0 - g * g) / (4.0 * math.pi * denominator)


def sample_henyey_greenstein_cos(u, g):
    """cos(theta) of Henyey-Greenstein scattering from a uniform u (closed-form inverse)."""
    small = jnp.abs(g) < 1e-4
    safe_g = where(small, 1e-4, g)
    ratio = (1.0 - safe_g * safe_g) / (1.0 - safe_g + 2.0 * safe_g * u)
    mu = (1.0 + safe_g * safe_g - ratio * ratio) / (2.0 * safe_g)
    return clip(where(small, 2.0 * u - 1.0, mu), -1.0, 1.0)


def orthonormal_basis(direction):
    """Two unit vectors (..., 3) perpendicular to ``direction`` and to each other."""
    helper = where(
        (jnp.abs(direction[..., 2]) < 0.9)[..., None],
        jnp.array([0.0, 0.0, 1.0], direction.dtype),
        jnp.array([1.0, 0.0, 0.0], direction.dtype),
    )
    components = _components(direction)
    e1 = jnp.stack(cross_xyz(components, _components(helper)), axis=-1)
    e1 = e1 / jnp.sqrt(jnp.sum(e1 * e1, axis=-1, keepdims=True))
    return e1, jnp.stack(cross_xyz(components, _components(e1)), axis=-1)


def _components(vectors):
    """(..., 3) vectors as a 3-tuple of (...) arrays (inline; ``jnp.cross`` and
    ``jnp.linalg.norm`` are nested jitted programs)."""
    return vectors[..., 0], vectors[..., 1], vectors[..., 2]


def deflect(direction, cos_theta, phi):
    """Turn unit ``direction`` by polar angle acos(cos_theta) at azimuth ``phi`` (rad)."""
    e1, e2 = orthonormal_basis(direction)
    sin_squared = 1.0 - cos_theta**2
    inside = sin_squared > 0
    # sqrt with a zero (not infinite) derivative at sin = 0, so gradients stay finite
    sin_theta = where(inside, jnp.sqrt(where(inside, sin_squared, 1.0)), 0.0)
    return (
        cos_theta[..., None] * direction
        + (sin_theta * jnp.cos(phi))[..., None] * e1
        + (sin_theta * jnp.sin(phi))[..., None] * e2
    )


def lambertian_direction(normal, u1, u2):
    """A cosine-law direction about the (inward) ``normal`` from uniforms u1, u2."""
    return deflect(normal, jnp.sqrt(u1), 2.0 * math.pi * u2)


def lambertian_density(cos_out):
    """Radiance of a Lambertian reflector per steradian: cos / pi (0 behind the wall)."""
    return jnp.maximum(cos_out, 0.0) / math.pi


def specular_direction(direction, normal):
    """Mirror ``direction`` about the plane with unit ``normal``."""
    return direction - 2.0 * jnp.sum(direction * normal, axis=-1, keepdims=True) * normal


def dome_normal(offset, normal, radius):
    """Normal of the hemispherical dome over a sensor disc, at in-plane ``offset`` (..., 3)
    m from the disc centre (normal (..., 3) unit, radius (...,) m)."""
    in_plane = offset - jnp.sum(offset * normal, axis=-1, keepdims=True) * normal
    rho2 = jnp.sum(in_plane * in_plane, axis=-1, keepdims=True)
    r = radius[..., None]
    inside = r * r - rho2 > 0
    height = where(inside, jnp.sqrt(where(inside, r * r - rho2, 1.0)), 0.0)
    dome = (in_plane + height * normal) / r
    return dome / jnp.linalg.norm(dome, axis=-1, keepdims=True)


def dome_reflection_density(direction_in, direction_out, normal):
    """Directions of light reflected off a sensor's dome, per steradian per reflected photon.

    For photons crossing the disc uniformly from ``direction_in`` and mirrored about
    ``dome_normal``: p(w_out) = (h . n) / (4 pi (w_out . h)), h the unit half vector
    (w_out - w_in) / |w_out - w_in|, zero where h . n <= 0. It integrates to 1 over the
    sphere (isotropic at normal incidence, like a mirror ball).
    """
    half = direction_out - direction_in
    norm = jnp.sqrt(jnp.maximum(jnp.sum(half * half, axis=-1), 1e-30))
    h_n = jnp.sum(half * normal, axis=-1) / norm
    h_out = jnp.sum(half * direction_out, axis=-1) / norm
    valid = (h_n > 0) & (h_out > 0)
    return where(valid, h_n / (4.0 * math.pi * where(valid, h_out, 1.0)), 0.0)


def dome_reflection_density_cos(cos_turn, cos_out, in_normal):
    """``dome_reflection_density`` from cosines: u . i (``cos_turn``), u . n (``cos_out``)
    and i . n (``in_normal``), u the outgoing and i the incoming direction, n the disc
    normal: (u . n - i . n) / (4 pi (1 - u . i)) where u . n > i . n, else 0."""
    valid = (cos_out > in_normal) & (cos_turn < 1.0)
    safe = where(valid, 1.0 - cos_turn, 1.0)
    return where(valid, (cos_out - in_normal) / (4.0 * math.pi * safe), 0.0)


# ---- the same on x, y, z components (structure of arrays) -------------------------------
# Vectors are 3-tuples of arrays that broadcast together: XLA fuses the component-wise
# arithmetic of a whole batch into single loops, where (..., 3) arrays need reductions.


def dot_xyz(a, b):
    """Dot product of two component 3-tuples."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross_xyz(a, b):
    """Cross product a x b of two component 3-tuples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def deflect_xyz(direction, cos_theta, phi):
    """``deflect`` on components: unit ``direction`` turned by polar angle acos(cos_theta)
    at azimuth ``phi`` (rad) about the basis of ``orthonormal_basis``.

    The basis is left unnormalised (u = d x helper, v = d x u, both of length |u|) and
    1 / |u| is folded into the azimuth factors, which then end in a division: XLA on CPU
    evaluates those once per photon, not once per output component (sin and cos count
    as cheap and would be recomputed for each).
    """
    use_z = jnp.abs(direction[2]) < 0.9
    zero, one = jnp.zeros_like(direction[2]), jnp.ones_like(direction[2])
    u = cross_xyz(direction, (where(use_z, zero, one), zero, where(use_z, one, zero)))
    v = cross_xyz(direction, u)
    length = jnp.sqrt(dot_xyz(u, u))
    sin_squared = 1.0 - cos_theta**2
    inside = sin_squared > 0
    # sqrt with a zero (not infinite) derivative at sin = 0, so gradients stay finite
    sin_theta = where(inside, jnp.sqrt(where(inside, sin_squared, 1.0)), 0.0)
    along_u = sin_theta * jnp.cos(phi) / length
    along_v = sin_theta * jnp.sin(phi) / length
    return tuple(
        cos_theta * d + along_u * a + along_v * b for d, a, b in zip(direction, u, v, strict=True)
    )


def specular_direction_xyz(direction, normal):
    """``specular_direction`` on components: ``direction`` mirrored about unit ``normal``."""
    twice = 2.0 * dot_xyz(direction, normal)
    return tuple(d - twice * n for d, n in zip(direction, normal, strict=True))


def dome_normal_xyz(offset, normal, radius):
    """``dome_normal`` on components: the unit normal of the hemispherical dome over a
    sensor disc at ``offset`` (m) from the disc centre; ``normal`` unit, ``radius`` m."""
    along = dot_xyz(offset, normal)
    in_plane = tuple(q - along * n for q, n in zip(offset, normal, strict=True))
    rho2 = dot_xyz(in_plane, in_plane)
    inside = radius * radius - rho2 > 0
    height = where(inside, jnp.sqrt(where(inside, radius * radius - rho2, 1.0)), 0.0)
    dome = tuple((q + height * n) / radius for q, n in zip(in_plane, normal, strict=True))
    length = jnp.sqrt(dot_xyz(dome, dome))
    return tuple(c / length for c in dome)


def travel_time(distance, params: Params):
    """Time (ns) for light to travel ``distance`` (m) at the group velocity c / n_g."""
    return distance * params.group_index / SPEED_OF_LIGHT
