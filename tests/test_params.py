"""Params: replace, unconstrained transforms, validation, defaults, no recompilation."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from photonflow.errors import ConfigError
from photonflow.geometry import preset_detector
from photonflow.medium import SCINTILLATOR, WATER
from photonflow.params import (
    PARAM_SPECS,
    Params,
    default_params,
    from_unconstrained,
    to_unconstrained,
    validate_params,
)
from photonflow.photosensors import SENSOR_MODELS, SK_ANGULAR_ACCEPTANCE

FIELDS = [spec.name for spec in PARAM_SPECS]


@pytest.fixture(scope="module")
def toy():
    return preset_detector("TOY_CYLINDER")


def test_contract_field_names(toy):
    """The field names are a public contract (issue 2)."""
    assert FIELDS == [
        "absorption_length",
        "scattering_length",
        "mie_length",
        "mie_g",
        "refractive_index",
        "group_index",
        "wall_reflectivity",
        "wall_specular_fraction",
        "sensor_reflectivity",
        "quantum_efficiency",
        "efficiency",
        "time_offset",
        "tts",
        "spe_width",
        "dark_rate",
        "angular_acceptance",
    ]
    params = default_params(toy)
    assert params.efficiency.shape == (toy.n_sensors,)
    assert params.time_offset.shape == (toy.n_sensors,)
    assert params.angular_acceptance.shape == (10,)


def test_water_defaults_from_reference_sheet():
    """SK in water: WCSim tuned water at 400 nm and the R3600 sensor values."""
    params = default_params(preset_detector("SK"))
    assert float(params.absorption_length) == pytest.approx(425 * 1.30, rel=1e-6)
    assert float(params.scattering_length) == pytest.approx(176 * 0.75, rel=1e-6)
    assert float(params.refractive_index) == pytest.approx(1.3442, rel=1e-6)
    assert float(params.quantum_efficiency) == pytest.approx(0.211, rel=1e-6)
    assert float(params.dark_rate) == pytest.approx(4200.0)
    assert float(params.wall_reflectivity) == pytest.approx(0.045 * 2.5, rel=1e-6)
    assert float(params.sensor_reflectivity) == pytest.approx(0.32, rel=1e-6)
    assert math.isinf(float(params.mie_length))
    np.testing.assert_allclose(params.angular_acceptance, SK_ANGULAR_ACCEPTANCE, rtol=1e-6)
    assert params.absorption_length.dtype == jnp.float32  # float32 by default


def test_scintillator_defaults():
    params = default_params(preset_detector("JUNO"), medium="scintillator")
    assert float(params.refractive_index) == pytest.approx(SCINTILLATOR.refractive_index)
    assert float(params.absorption_length) == pytest.approx(62.0)
    assert float(params.scattering_length) == pytest.approx(27.0)
    assert float(params.quantum_efficiency) == pytest.approx(
        SENSOR_MODELS["R12860"].quantum_efficiency
    )
    assert SCINTILLATOR.group_index > SCINTILLATOR.refractive_index
    assert WATER.group_index > WATER.refractive_index


def test_open_medium_has_no_wall_reflection():
    params = default_params(preset_detector("ICECUBE_MINI"))
    assert float(params.wall_reflectivity) == 0.0


def test_unknown_medium(toy):
    with pytest.raises(ConfigError, match="medium = 'oil'"):
        default_params(toy, medium="oil")


def test_replace_returns_modified_copy(toy):
    params = default_params(toy)
    changed = params.replace(absorption_length=80.0, efficiency=jnp.full(toy.n_sensors, 0.9))
    assert float(changed.absorption_length) == 80.0
    assert float(params.absorption_length) == pytest.approx(552.5)  # original untouched
    np.testing.assert_allclose(changed.efficiency, 0.9)
    assert changed.absorption_length.dtype == params.absorption_length.dtype
    # A scalar broadcasts over a per-sensor field.
    assert params.replace(time_offset=1.5).time_offset.shape == (toy.n_sensors,)
    with pytest.raises(dataclasses.FrozenInstanceError):
        params.absorption_length = 3.0


def test_replace_rejects_unknown_field_and_bad_shape(toy):
    params = default_params(toy)
    with pytest.raises(ConfigError, match="params.absorbtion_length: unknown"):
        params.replace(absorbtion_length=1.0)
    with pytest.raises(ConfigError, match=r"params.efficiency: shape \(3,\)"):
        params.replace(efficiency=jnp.ones(3))


def test_unconstrained_round_trip_defaults(toy):
    with jax.enable_x64(True):
        params = default_params(toy).replace(dark_rate=0.0)
        back = from_unconstrained(to_unconstrained(params))
        for name in FIELDS:
            np.testing.assert_allclose(getattr(back, name), getattr(params, name), rtol=1e-12)


@given(
    length=st.floats(1e-3, 1e4),
    probability=st.floats(1e-6, 1 - 1e-6),
    g=st.floats(-0.999, 0.999),
    index=st.floats(1.0001, 2.5),
    offset=st.floats(-100, 100),
)
def test_unconstrained_round_trip_property(length, probability, g, index, offset):
    with jax.enable_x64(True):
        params = default_params(preset_detector("TOY_SPHERE")).replace(
            absorption_length=length,
            wall_reflectivity=probability,
            mie_g=g,
            refractive_index=index,
            time_offset=offset,
        )
        unconstrained = params.to_unconstrained()
        assert all(
            bool(jnp.all(jnp.isfinite(leaf)))
            for leaf in jax.tree.leaves(
                dataclasses.replace(unconstrained, mie_length=jnp.asarray(0.0))
            )
        )
        back = Params.from_unconstrained(unconstrained)
        for name in (
            "absorption_length",
            "wall_reflectivity",
            "mie_g",
            "refractive_index",
            "time_offset",
        ):
            np.testing.assert_allclose(
                getattr(back, name), getattr(params, name), rtol=1e-9, atol=1e-12
            )


def test_unconstrained_coordinates_are_the_documented_maps(toy):
    with jax.enable_x64(True):
        params = default_params(toy).replace(absorption_length=100.0, wall_reflectivity=0.2)
        u = to_unconstrained(params)
        assert float(u.absorption_length) == pytest.approx(math.log(100.0))
        assert float(u.wall_reflectivity) == pytest.approx(math.log(0.2 / 0.8))
        assert float(u.refractive_index) == pytest.approx(math.log(params.refractive_index - 1))


def test_no_recompilation_when_values_change(toy):
    traces = []

    @jax.jit
    def attenuation(params):
        traces.append(1)
        return jnp.exp(-10.0 / params.absorption_length) * jnp.sum(params.efficiency)

    params = default_params(toy)
    first = attenuation(params)
    second = attenuation(params.replace(absorption_length=50.0))
    third = attenuation(params.replace(efficiency=params.efficiency * 0.5, tts=3.0))
    assert len(traces) == 1
    assert float(second) < float(first)
    assert float(third) == pytest.approx(0.5 * float(first), rel=1e-6)


def test_params_is_a_pytree_with_one_leaf_per_field(toy):
    leaves, treedef = jax.tree.flatten(default_params(toy))
    assert len(leaves) == len(FIELDS)
    grads = jax.grad(lambda p: p.absorption_length**2)(default_params(toy))
    assert isinstance(grads, Params)


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"absorption_length": -5.0}, "params.absorption_length = -5 m: must be > 0"),
        ({"scattering_length": float("nan")}, "params.scattering_length = nan m: is NaN"),
        ({"wall_reflectivity": 1.5}, "params.wall_reflectivity = 1.5: must be in [0, 1]"),
        ({"quantum_efficiency": -0.1}, "params.quantum_efficiency = -0.1: must be in [0, 1]"),
        ({"mie_g": 1.0}, "params.mie_g = 1: must be in (-1, 1)"),
        ({"refractive_index": 0.9}, "params.refractive_index = 0.9"),
        ({"time_offset": float("inf")}, "params.time_offset[0] = inf ns: must be finite"),
    ],
)
def test_validation_messages(toy, change, fragment):
    params = default_params(toy).replace(**change)
    with pytest.raises(ConfigError) as info:
        validate_params(params, toy.n_sensors)
    assert fragment in str(info.value)


def test_validation_accepts_defaults_and_reports_sensor_index(toy):
    params = default_params(toy)
    assert validate_params(params, toy.n_sensors) is params
    bad = params.replace(efficiency=params.efficiency.at[17].set(-1.0))
    with pytest.raises(ConfigError, match=r"params.efficiency\[17\] = -1"):
        validate_params(bad, toy.n_sensors)
    with pytest.raises(ConfigError, match=r"params.efficiency: shape \(200,\), expected \(5,\)"):
        validate_params(params, 5)


def test_parameters_doc_lists_every_field_with_its_unit():
    """docs/parameters.md documents every field (a new field must be documented)."""
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs" / "parameters.md").read_text()
    for spec in PARAM_SPECS:
        row = next((line for line in doc.splitlines() if line.startswith(f"| `{spec.name}`")), "")
        assert row, f"{spec.name} missing from docs/parameters.md"
        assert f"| {spec.unit or '-'} |" in row
