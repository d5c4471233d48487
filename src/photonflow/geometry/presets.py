"""Detector presets with dimensions and sensor counts from the reference sheet.

Every preset cites its numbers (``shared/reference/physics.md`` section 5 unless said
otherwise). ``PRESETS[name].stated`` holds the published sensor count and coverage the
layout must reproduce (tested within 1 %); where a number is not published the field
is ``None``. Layout details that are not published (grid type of the caps, mPMT tilt
angles) are the generator's choice and said so.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

from ..errors import ConfigError, format_value
from ..photosensors import sensor_model
from .detector import Detector, make_detector
from .layouts import (
    barrel_caps_layout,
    barrel_caps_layout_for_coverage,
    expand_modules,
    fibonacci_sphere_layout,
    latitude_rings_sphere_layout,
    string_layout,
)
from .shapes import Cylinder, OpenMedium, Sphere


@dataclasses.dataclass(frozen=True)
class Stated:
    """Published figures a preset reproduces: sensor count and coverage (fraction)."""

    sensors: int | None
    coverage: float | None
    source: str


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named detector: a builder and the figures it must match."""

    name: str
    build: Callable[[], Detector]
    stated: Stated
    medium: str = "water"

    @property
    def description(self) -> str:
        """First line of the builder's docstring."""
        return (self.build.__doc__ or "").strip().splitlines()[0]


def _single_model(name, shape, positions, normals, model) -> Detector:
    radius = sensor_model(model).radius
    return make_detector(shape, positions, normals, radius, 0, name=name, sensor_models=(model,))


def super_kamiokande() -> Detector:
    """Super-Kamiokande inner detector: 33.68 m x 36.20 m, 11,146 20-inch PMTs, ~40 %.

    ID 33.6815 m diameter x 36.200 m (WCSim WCSimDetectorConfigs.cc); 11,146 ID PMTs
    of radius 0.254 m (WCSim WCSimPMTObject.cc); 70 cm spacing, ~40 % coverage (SK
    site). Layout: 51 rings x 150 columns on the barrel (7,650) and 1,748 per cap on a
    square grid, which reproduces the count and the 70.7 cm pitch.
    """
    shape = Cylinder(radius=33.6815 / 2, height=36.2)
    positions, normals = barrel_caps_layout(
        shape.radius, shape.height, 51, 150, 1748, cap_margin=0.254
    )
    return _single_model("SK", shape, positions, normals, "R3600")


def hyper_kamiokande() -> Detector:
    """Hyper-Kamiokande inner detector: 64.8 m x 65.75 m, 20 % coverage with 20-inch PMTs.

    ID 64.8 m diameter x 65.751 m and 20 % B&L coverage (WCSim WCSimDetectorConfigs.cc,
    hybrid configuration; the 5 % mPMT share is not modelled). Box-and-line R12860
    PMTs of radius 0.254 m; square grid on barrel and caps at the pitch that gives 20 %.
    """
    shape = Cylinder(radius=64.8 / 2, height=65.751)
    positions, normals = barrel_caps_layout_for_coverage(shape.radius, shape.height, 0.20, 0.254)
    return _single_model("HK", shape, positions, normals, "R12860")


def _mpmt_detector(name: str, shape: Cylinder, rings: int, columns: int, cap: int) -> Detector:
    vessel_radius = 0.254  # mPMT vessel radius, WCSim WCSimDetectorConfigs.cc
    modules, module_normals = barrel_caps_layout(
        shape.radius, shape.height, rings, columns, cap, cap_margin=vessel_radius
    )
    positions, normals, _ = expand_modules(modules, module_normals, vessel_radius)
    return _single_model(name, shape, positions, normals, "R14374")


def iwcd() -> Detector:
    """IWCD: 7.0 m x 8.0 m, 368 mPMTs x 19 3-inch PMTs (24 x 11 on the barrel, 52 per cap).

    ID 7.0 m diameter x 8.0 m; mPMTs of 19 x 3-inch R12199-02-like PMTs, 24 per ring x
    11 rings on the barrel, 52 per cap (WCSim WCSimDetectorConfigs.cc comment). The
    modules' PMTs sit on a dome of the vessel radius 0.254 m (tilts assumed, see
    ``layouts.MPMT_RINGS``).
    """
    return _mpmt_detector("IWCD", Cylinder(radius=3.5, height=8.0), 11, 24, 52)


def wcte() -> Detector:
    """WCTE: 3.076 m x 2.714 m, 106 mPMT slots x 19 3-inch PMTs.

    ID 3.076 m diameter x 2.714 m, 19 x 3-inch R14374 per mPMT, 106 slots in WCSim's
    data/mPMT_Position_WCTE.txt (NuPRISMBeamTest_16cShort_mPMT). Layout: 4 rings x 16
    columns on the barrel and 21 per cap (64 + 2 x 21 = 106 slots).
    """
    return _mpmt_detector("WCTE", Cylinder(radius=3.076 / 2, height=2.714), 4, 16, 21)


#: Radius (m) of JUNO's 20-inch PMT sphere chosen so that the 17,612 PMTs give the
#: quoted 78 % coverage. It lies between the acrylic vessel (17.82 m outer radius) and
#: the steel shell (20.05 m). The quoted figure includes the 25,600 3-inch PMTs, which
#: are not modelled, so the 20-inch share is slightly overstated.
JUNO_PMT_SPHERE_RADIUS = math.sqrt(17612 * 0.254**2 / (4 * 0.78))


def juno() -> Detector:
    """JUNO central detector: 35.4 m acrylic sphere, 17,612 20-inch PMTs, 78 % coverage.

    Acrylic sphere 35.4 m inner diameter, steel shell 40.1 m, 17,612 20-inch PMTs,
    78 % coverage (NST 36:84, 2025; indico.cern.ch/event/1291157). The optical
    boundary is the PMT sphere (``JUNO_PMT_SPHERE_RADIUS``); the acrylic vessel and
    the water buffer are not separate media. Latitude rings (as JUNO mounts its PMTs;
    a Fibonacci lattice's discs would overlap at 78 %); R12860 values for the
    sensors (JUNO's Hamamatsu 20-inch PMTs are that model).
    """
    shape = Sphere(radius=JUNO_PMT_SPHERE_RADIUS)
    positions, normals = latitude_rings_sphere_layout(shape.radius, 17612, min_pitch=0.508)
    return _single_model("JUNO", shape, positions, normals, "R12860")


#: TAO: photosensitive SiPM area (m^2) and the radius (m) of the sphere it tiles.
TAO_SIPM_AREA = 10.0
TAO_SIPM_SPHERE_RADIUS = 1.02


def tao() -> Detector:
    """TAO: 1.8 m acrylic sphere of GdLS viewed by ~10 m^2 of SiPM tiles.

    1.8 m diameter acrylic sphere, ~10 m^2 of SiPMs with > 50 % PDE (arXiv:2005.08745).
    Tiles modelled as 4,000 discs of 25 cm^2 each (10 m^2) in latitude rings on a
    sphere of 1.02 m. The radius of the tile shell is not in the reference sheet;
    1.02 m puts the tiles outside the 0.9 m vessel and keeps the discs (which, unlike
    square tiles, cannot cover more than ~78 % in rings) from overlapping.
    """
    count = 4000
    shape = Sphere(radius=TAO_SIPM_SPHERE_RADIUS)
    radius = math.sqrt(TAO_SIPM_AREA / count / math.pi)
    positions, normals = latitude_rings_sphere_layout(shape.radius, count, min_pitch=2 * radius)
    return make_detector(shape, positions, normals, radius, 0, name="TAO", sensor_models=("SiPM",))


def eos() -> Detector:
    """Eos: ~20 t water-based scintillator tank viewed by 206 8-inch PMTs.

    ~20 t, 206 x 8-inch R14688-100 PMTs (arXiv:2311.05080). The tank dimensions are
    not in the reference sheet: an upright cylinder of equal diameter and height
    holding 20 m^3 (2.94 m x 2.94 m) is used, with 5 rings x 30 columns on the barrel
    and 28 per cap (150 + 56 = 206).
    """
    side = (4 * 20.0 / math.pi) ** (1 / 3)
    shape = Cylinder(radius=side / 2, height=side)
    positions, normals = barrel_caps_layout(
        shape.radius, shape.height, 5, 30, 28, cap_margin=0.1016
    )
    return _single_model("EOS", shape, positions, normals, "R14688")


def icecube_mini() -> Detector:
    """A 7-string open-medium array (IceCube-like): 7 x 60 downward-looking 10-inch PMTs.

    IceCube geometry (detector paper, JINST 12 P03012): strings 125 m apart on a
    triangular lattice, 60 DOMs per string 17 m apart, 10-inch PMTs looking down.
    Seven strings (a centre and its hexagon). The simulated world extends 200 m beyond
    the array.
    """
    positions, normals = string_layout(7, 125.0, 60, 17.0)
    shape = OpenMedium(world_radius=125.0 + 200.0, world_height=59 * 17.0 + 400.0)
    return _single_model("ICECUBE_MINI", shape, positions, normals, "R7081")


def toy_cylinder() -> Detector:
    """A small water cylinder for fast tests: 4 m x 4 m, 200 8-inch PMTs.

    Not a real detector: 4 rings x 30 columns on the barrel and 40 per cap of
    R14688-like 8-inch PMTs.
    """
    shape = Cylinder(radius=2.0, height=4.0)
    positions, normals = barrel_caps_layout(
        shape.radius, shape.height, 4, 30, 40, cap_margin=0.1016
    )
    return _single_model("TOY_CYLINDER", shape, positions, normals, "R14688")


def toy_sphere() -> Detector:
    """A small sphere for fast tests: 4 m diameter, 300 8-inch PMTs (Fibonacci lattice)."""
    shape = Sphere(radius=2.0)
    positions, normals = fibonacci_sphere_layout(shape.radius, 300)
    return _single_model("TOY_SPHERE", shape, positions, normals, "R14688")


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset("SK", super_kamiokande, Stated(11146, 0.40, "WCSim; SK site: ~40 %")),
        Preset("HK", hyper_kamiokande, Stated(None, 0.20, "WCSim hybrid: 20 % B&L")),
        Preset("IWCD", iwcd, Stated(368 * 19, None, "WCSim: (24 x 11 + 2 x 52) x 19")),
        Preset("WCTE", wcte, Stated(106 * 19, None, "WCSim mPMT_Position_WCTE.txt: 106 x 19")),
        Preset("JUNO", juno, Stated(17612, 0.78, "NST 36:84 (2025)"), medium="scintillator"),
        Preset(
            "TAO", tao, Stated(None, None, "arXiv:2005.08745: ~10 m^2 SiPM"), medium="scintillator"
        ),
        Preset("EOS", eos, Stated(206, None, "arXiv:2311.05080")),
        Preset("ICECUBE_MINI", icecube_mini, Stated(7 * 60, None, "IceCube: 60 DOMs/string")),
        Preset("TOY_CYLINDER", toy_cylinder, Stated(200, None, "toy")),
        Preset("TOY_SPHERE", toy_sphere, Stated(300, None, "toy")),
    )
}


def preset_detector(name: str) -> Detector:
    """The ``Detector`` of a preset (case-insensitive name); built once and cached."""
    key = str(name).upper()
    if key not in PRESETS:
        raise ConfigError(
            f"detector = {format_value(name)}: unknown preset; known: {', '.join(PRESETS)}"
        )
    return _build_preset(key)


@functools.cache
def _build_preset(key: str) -> Detector:
    return PRESETS[key].build()


def preset_table() -> list[dict[str, object]]:
    """One row per preset: name, shape, dimensions, sensors, coverage (fraction or nan),
    sensor model, medium and source (where its published figures come from)."""
    rows = []
    for preset in PRESETS.values():
        detector = preset_detector(preset.name)
        rows.append(
            {
                "name": preset.name,
                "shape": detector.shape.kind,
                "dimensions": detector.shape.describe(),
                "sensors": detector.n_sensors,
                "coverage": detector.coverage,
                "sensor_model": ", ".join(detector.sensor_models),
                "medium": preset.medium,
                "source": preset.stated.source,
            }
        )
    return rows
