"""The root ``photonflow`` typer app, the helpers every command shares (``fail``,
``guarded``, ``command``, ``console``) and the console entry ``main``.

The commands themselves live in the sibling modules; ``photonflow.cli`` registers
them on ``app``.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Annotated, TypeVar

import typer
from rich.console import Console

from .. import __version__
from ..cli_errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, error_line, out_of_memory
from ..errors import PhotonflowError

app = typer.Typer(
    name="photonflow",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)

F = TypeVar("F", bound=Callable)


def fail(message: str) -> typer.Exit:
    """Print ``error: <message>`` as one line on stderr; return the exit to raise (code 2)."""
    error_line(message)
    return typer.Exit(code=EXIT_BAD_INPUT)


def guarded(function: F) -> F:
    """``function`` with bad input (any ``PhotonflowError``) and running out of memory
    reported as one ``error:`` line and exit code 2, and an interrupt ending in exit
    code 130."""

    @functools.wraps(function)
    def run(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except PhotonflowError as error:
            raise fail(str(error)) from None
        except KeyboardInterrupt:  # the console entry says "interrupted"
            raise typer.Exit(code=EXIT_INTERRUPTED) from None
        except Exception as error:
            if not out_of_memory(error):
                raise
            raise fail(f"out of memory ({type(error).__name__}); ask for less: fewer"
                       " --events, --photons or --rays") from None

    return run


def command(function: F) -> F:
    """Register ``function`` as a sub-command of ``photonflow`` (``guarded``)."""
    app.command()(guarded(function))
    return function


def console(width: int = 120) -> Console:
    """A rich console on stdout; ``width`` columns wide when stdout is not a terminal
    (pipes, files), so that tables are not squeezed to the 80-column default."""
    return Console() if sys.stdout.isatty() else Console(width=width)


def _version(show: bool) -> None:
    if show:
        print(f"photonflow {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True,
                     help="Print the version and exit."),
    ] = False,
) -> None:
    """Differentiable simulation, calibration and reconstruction of optical particle
    detectors (units: m, ns, MeV, rad)."""


def main() -> None:
    """Entry point of the ``photonflow`` console script and ``python -m photonflow``
    (``cli_errors.run_console``: usage errors as one line, exit 130 when interrupted)."""
    from .._startup import release
    from ..cli_errors import run_console
    from ..garbage_collection import collect_less_often

    release()  # run_console handles interrupts from here on
    collect_less_often()  # tracing ~20 % faster (photonflow.garbage_collection)
    run_console(app, prog_name="photonflow")
