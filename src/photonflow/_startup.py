"""Interrupts while the ``photonflow`` command is still starting.

Importing photonflow imports JAX (about a second). A Ctrl-C or ``kill`` in that second,
before the command's own interrupt handling is in place (``cli_errors.run_console``),
would end in Python's traceback (or, inside jaxlib's import, a crash). When photonflow
is imported as the console command (``photonflow ...`` or ``python -m photonflow``),
``guard_command_start`` makes both signals end the process at once with one line and
exit code 130: nothing has been done yet. Imported as a library, nothing changes.
The guard is set when this module is imported, which ``photonflow/__init__.py`` does
first.
"""

from __future__ import annotations

import os
import signal
import sys

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: What the process is called when it runs the console command.
_COMMAND_NAMES = ("photonflow", "photonflow.exe", "-m")


def _starting(signum, frame) -> None:  # pragma: no cover - exits the process
    os.write(2, b"interrupted while photonflow was starting (nothing was done)\n")
    os._exit(130)


def running_as_command() -> bool:
    """Whether this process is the ``photonflow`` command (``python -m photonflow``
    shows as "-m" while the package is imported)."""
    return bool(sys.argv) and os.path.basename(sys.argv[0]) in _COMMAND_NAMES


def guard_command_start() -> None:
    """In the console command, exit 130 with one line on SIGINT or SIGTERM until
    ``release`` (called first thing by the command's entry point)."""
    if running_as_command():
        for number in _SIGNALS:
            signal.signal(number, _starting)


def release() -> None:
    """Give SIGINT and SIGTERM back to their defaults where the guard holds them."""
    for number in _SIGNALS:
        if signal.getsignal(number) is _starting:
            signal.signal(number, signal.default_int_handler if number == signal.SIGINT
                          else signal.SIG_DFL)


guard_command_start()
