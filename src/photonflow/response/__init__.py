"""The sensor response: what a photosensor makes of the light that reaches it.

One stage per mode, after the transport (``photonflow.transport``), which delivers
light arriving at each sensor:

- ``detection``: the probability that an arriving photon becomes a photoelectron
  (QE x relative efficiency x angular acceptance), shared by both modes, and the fate
  of a photon meeting a sensor in the sampled mode;
- ``expected``: the expected mode's response, ``SensorLight`` -> ``Prediction``
  (efficiency, time offset, transit-time spread);
- ``hits``: the sampled mode's response after detection, photoelectrons -> hits
  (transit-time spread, time offset, dark noise, single-p.e. charges, readout window,
  threshold);
- ``spe``: the single-photoelectron charge model shared by ``hits`` and the likelihood.
"""

from .detection import acceptance_at_cos, detection_probability, sensor_fate
from .expected import SensorLight, expected_response
from .hits import photoelectrons_to_event, single_pe_charges
from .spe import single_pe_moments

__all__ = [
    "SensorLight",
    "acceptance_at_cos",
    "detection_probability",
    "expected_response",
    "photoelectrons_to_event",
    "sensor_fate",
    "single_pe_charges",
    "single_pe_moments",
]
