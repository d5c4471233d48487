"""The ``photonflow`` command: parse, call the library, write, report.

Every command reports bad input (any ``PhotonflowError``) as one line
``error: <message>`` on stderr and exits with code 2, without a traceback; pictures
and files are written under a temporary name and renamed, so a failed command leaves
nothing behind.

One module per idea: ``root`` (the typer app, its shared helpers and ``main``),
``show`` (presets, geometry, info, display), ``simulate`` with ``light`` (its
calibration source or particle tracks), ``calibrate``, ``reconstruct`` (with
``evaluate``), ``demo``, ``benchmark`` and
``tables``. This package registers the commands on ``app`` in the order that
``photonflow --help`` lists them.
"""

from __future__ import annotations

from ..interrupts import terminate_as_interrupt
from . import calibrate, demo, reconstruct, show, simulate
from .benchmark import benchmark_app
from .root import app, command, main
from .tables import tables_app

__all__ = ["app", "main", "terminate_as_interrupt"]

for _function in (show.presets, show.geometry, show.info, simulate.simulate, show.display,
                  calibrate.calibrate, reconstruct.reconstruct, reconstruct.evaluate,
                  demo.demo):
    command(_function)
del _function
app.add_typer(benchmark_app, name="benchmark")
app.add_typer(tables_app, name="tables")
