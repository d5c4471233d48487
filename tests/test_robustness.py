"""Finite predictions and gradients at every source position, degenerate ones included.

A source in a symmetry plane of the sensor array, on the axis, on a sensor's normal line
or 1 cm from a wall puts some path of the expected mode on a degenerate geometry (a
reflection point on the sensor itself, a ray along a face, a tangent root). Such paths
once gave NaN charges on the toy cylinder's cap sensors for every source at z = 0.41 m.
Property-based: hypothesis draws positions and source settings, and the degenerate
points of each shape are always tried first (``example``). For every shape (cylinder,
sphere, box, open medium) and every source type the charge, the time mixture, the
likelihood and its gradient with respect to every ``Params`` field and every source
field must be finite.
"""

from __future__ import annotations

import functools
import math

import jax
import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import photonflow as pf
from photonflow.geometry.layouts import box_grid_layout, string_layout
from photonflow.transport.expected import expected_function

pytestmark = pytest.mark.compile_bound

#: Small transport settings: every path type (bounces, probes, mirror quadrature) runs.
CONFIG = pf.TransportConfig(n_bounces=2, n_rays=32, specular_probes=2)
KINDS = ("isotropic", "laser", "diffuser")
#: Degenerate points tried for each shape (always), then this many drawn ones.
DRAWN = 6


def _box_detector():
    shape = pf.Box(3.0, 3.0, 3.0)
    positions, normals = box_grid_layout(3.0, 3.0, 3.0, 0.75)
    return pf.make_detector(shape, positions, normals, 0.1016, name="TOY_BOX",
                            sensor_models=("R14688",))


def _open_detector():
    shape = pf.OpenMedium(world_radius=60.0, world_height=120.0)
    positions, normals = string_layout(3, 20.0, 6, 5.0)
    return pf.make_detector(shape, positions, normals, 0.1651, name="TOY_STRINGS",
                            sensor_models=("R7081",))


@functools.cache
def detector(shape: str):
    """The test detector of each shape (cached)."""
    if shape == "cylinder":
        return pf.load_detector("TOY_CYLINDER")
    if shape == "sphere":
        return pf.load_detector("TOY_SPHERE")
    if shape == "box":
        return _box_detector()
    return _open_detector()


def _sensor_normal_points(det, count=4, depths=(0.01, 0.3, 1.0)):
    """Points on the normal lines of a few sensors (first, last, spread between)."""
    picks = np.linspace(0, det.n_sensors - 1, count).astype(int)
    return [det.sensor_positions[i] + d * det.sensor_normals[i] for i in picks for d in depths]


def degenerate_points(shape: str) -> list[tuple[float, float, float]]:
    """Positions (m) on the degenerate geometry of each shape: centre, axis, symmetry
    planes through sensor rows and columns, diagonals, 1 cm from walls and caps, sensor
    normal lines, round numbers and a fine scan in height."""
    det = detector(shape)
    points = [np.zeros(3)]
    if shape == "cylinder":
        r, h = det.shape.radius, det.shape.height / 2
        heights = np.round(np.arange(-0.8 * h, 0.8 * h + 1e-9, 0.2 * h) + 0.01, 3)
        points += [np.array([0.0, 0.0, z]) for z in heights]  # axis, a fine height scan
        points += [np.array([0.0, -0.8, 0.4]), np.array([-0.6, 0.6, -0.6]),
                   np.array([0.198, -0.414, 0.41]), np.array([0.198, -0.414, -0.39])]
        points += [np.array([r - 0.01, 0.0, 0.0]), np.array([0.0, 0.0, h - 0.01]),
                   np.array([0.0, 0.0, -h + 0.01]), np.array([(r - 0.01) / math.sqrt(2)] * 2
                                                            + [h - 0.01])]
        column = np.arctan2(det.sensor_positions[0, 1], det.sensor_positions[0, 0])
        points += [np.array([0.5 * r * np.cos(column), 0.5 * r * np.sin(column), z])
                   for z in (0.0, det.sensor_positions[0, 2])]  # plane through a column
        points += [np.array([0.5, 0.5, 0.5]), np.array([1.0, 0.0, 0.41])]
    elif shape == "sphere":
        r = det.shape.radius
        points += [np.array([0.0, 0.0, z]) for z in (0.41, -0.39, 1.0, r - 0.01)]
        points += [np.array([r - 0.01, 0.0, 0.0]), np.array([0.5, 0.5, 0.5]),
                   (r - 0.01) * np.array([1.0, 1.0, 1.0]) / math.sqrt(3)]
    elif shape == "box":
        half = np.asarray(det.shape.half_sizes)
        points += [np.array([0.0, 0.0, z]) for z in (0.41, -0.39, half[2] - 0.01)]
        points += [np.array([half[0] - 0.01, 0.0, 0.0]), half - 0.01, -(half - 0.01),
                   np.array([0.5, 0.5, 0.0]), np.array([0.375, 0.375, 0.375])]
    else:
        points += [det.sensor_positions[0] + np.array([0.0, 0.0, -1.0]),
                   np.array([0.0, 0.0, 0.41]), np.array([10.0, 0.0, 2.5]),
                   np.array([20.0, 0.0, 0.0]), np.array([5.0, 5.0, 5.0])]
    points += _sensor_normal_points(det)
    return [tuple(float(x) for x in p) for p in points]


def _inside(shape: str):
    """A strategy for positions inside the shape (m), away from its walls by 1 cm."""
    det = detector(shape)
    unit = st.floats(-1.0, 1.0, allow_nan=False)
    if shape == "cylinder":
        r, h = det.shape.radius - 0.01, det.shape.height / 2 - 0.01
        return st.tuples(unit, unit, unit).filter(lambda p: p[0] ** 2 + p[1] ** 2 <= 1).map(
            lambda p: (r * p[0], r * p[1], h * p[2]))
    if shape == "sphere":
        r = det.shape.radius - 0.01
        return st.tuples(unit, unit, unit).filter(lambda p: sum(x * x for x in p) <= 1).map(
            lambda p: tuple(r * x for x in p))
    if shape == "box":
        half = np.asarray(det.shape.half_sizes) - 0.01
        return st.tuples(unit, unit, unit).map(
            lambda p: tuple(float(h * x)
                            for h, x in zip(half, p, strict=True)))
    return st.tuples(unit, unit, unit).map(lambda p: (30.0 * p[0], 30.0 * p[1], 30.0 * p[2]))


def make_source(kind: str, position, direction, setting: float):
    """A source of ``kind`` at ``position`` (m); ``setting`` in [0, 1] sets the laser's
    opening angle (0.02 .. pi rad) or the diffuser's anisotropy (-1 .. 1)."""
    common = {"position": position, "n_photons": 1e5, "time": 3.0, "pulse_width": 0.5}
    if kind == "isotropic":
        return pf.IsotropicSource(**common)
    direction = np.asarray(direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    if kind == "laser":
        return pf.LaserSource(direction=direction, opening_angle=0.02 + setting * (math.pi - 0.02),
                              **common)
    return pf.DiffuserSource(direction=direction, anisotropy=2.0 * setting - 1.0, **common)


@functools.cache
def checker(shape: str, kind: str):
    """Jitted (params, source) -> (prediction, nll, d nll / d params, d nll / d source),
    compiled once per shape and source kind, against one sampled event of the shape."""
    det = detector(shape)
    params = pf.default_params(det)
    truth = make_source("isotropic", [0.1, 0.05, 0.2], None, 0.0)
    event = pf.sample(det, params, truth, seed=3, config=CONFIG)
    predict = expected_function(det, config=CONFIG)

    def loss(p, source):
        prediction = predict(p, source, jax.random.key(1))
        return pf.nll(prediction, event), prediction

    gradient = jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)

    # compiled unoptimised (compile_bound) with XLA's classic CPU emitters (conftest): 13
    # instead of 27 s each, for a few dozen evaluations that then take 50 instead of
    # 15 ms on the toys
    @jax.jit
    def check(p, source):
        (value, prediction), (d_params, d_source) = gradient(p, source)
        return prediction, value, d_params, d_source

    return params, check


def assert_finite_everywhere(shape, kind, position, direction, setting):
    params, check = checker(shape, kind)
    source = make_source(kind, position, direction, setting)
    prediction, value, d_params, d_source = check(params, source)
    where = f"{shape}/{kind} at {position}"
    charge = np.asarray(prediction.charge)
    assert np.all(np.isfinite(charge)) and np.all(charge >= 0), f"charge at {where}"
    weight = np.asarray(prediction.time_weight)
    assert np.all(np.isfinite(weight)), f"time weights at {where}"
    np.testing.assert_allclose(weight.sum(axis=1), 1.0, atol=1e-4, err_msg=where)
    assert np.all(np.isfinite(np.asarray(prediction.time_mean))), f"time means at {where}"
    sigma = np.asarray(prediction.time_sigma)
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0), f"time sigmas at {where}"
    assert np.isfinite(float(value)), f"nll at {where}"
    for name, grad in vars(d_params).items():
        assert np.all(np.isfinite(np.asarray(grad))), f"d nll / d params.{name} at {where}"
    for name, grad in vars(d_source).items():
        assert np.all(np.isfinite(np.asarray(grad))), f"d nll / d source.{name} at {where}"


SHAPES = ("cylinder", "sphere", "box", "open")
DIRECTIONS = [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0),
              (0.3, -0.4, 0.866)]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape", SHAPES)
def test_degenerate_positions_give_finite_values_and_gradients(shape, kind):
    """Every degenerate point of the shape, with directions along the axes and the
    extreme settings (a 0.02 rad or 4 pi laser, a diffuser anisotropy of -1 or 1)."""
    for i, position in enumerate(degenerate_points(shape)):
        direction = DIRECTIONS[i % len(DIRECTIONS)]
        assert_finite_everywhere(shape, kind, position, direction, float(i % 2))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape", SHAPES)
def test_drawn_positions_give_finite_values_and_gradients(shape, kind):
    """Positions, directions and settings drawn by hypothesis (fixed seed)."""
    directions = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(
        lambda d: sum(x * x for x in d) > 0.01)

    @seed(22)
    @settings(max_examples=DRAWN, derandomize=True, database=None)
    @given(position=_inside(shape), direction=directions, setting=st.floats(0.0, 1.0))
    def drawn(position, direction, setting):
        assert_finite_everywhere(shape, kind, position, direction, setting)

    drawn()
