"""Bad command-line input, caught before any work, and the console entry's last word.

The ``photonflow`` command reports every bad input as one line ``error: ...`` on stderr
with exit code 2 and writes nothing. This module holds what makes that hold for the
whole command rather than option by option:

- the limits of the numeric options (``check_count``, ``check_number``), so that a
  run which could never end, or never fit in memory, is refused up front;
- checks of output paths before a long computation (``check_output_file``,
  ``check_output_folder``);
- options given on the command line that the chosen mode does not use
  (``refuse_unused``): an error, never silently ignored;
- ``run_console``: the console entry, which turns click's usage errors into one line,
  keeps warnings from printing ahead of an error, and ends an interrupted command
  with exit code 130.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import tempfile
import warnings
from pathlib import Path

from .errors import ConfigError, format_value
from .interrupts import INTERRUPT_SIGNALS

#: Exit codes of the command: bad input; a calibration that ran but did not converge;
#: an interrupted command (Ctrl-C, SIGTERM).
EXIT_BAD_INPUT = 2
EXIT_NOT_CONVERGED = 1
EXIT_INTERRUPTED = 130

#: Most events of one ``simulate`` run (split larger productions into runs with
#: different --seed): the tracks of a particle run are drawn up front, about 1 kB and
#: 60 us each.
MAX_EVENTS = 1_000_000
#: Most photons of one sampled event: photon-by-photon transport runs at about 1e6 to
#: 1e7 photons per second on a laptop CPU, so 1e10 photons take hours per event.
MAX_PHOTONS = 1e10
#: Fewest rays per source that ``calibrate`` accepts: with fewer, the expected mode's
#: indirect light is mostly ray noise and the fit's errors are meaningless.
MIN_CALIBRATION_RAYS = 32
#: Most rays per source of the expected mode (memory grows in proportion).
MAX_RAYS = 1 << 20
#: Most scatterings/reflections followed per photon or ray.
MAX_BOUNCES = 100
#: Most timed repetitions of a benchmark.
MAX_REPEATS = 1000


def max_workers() -> int:
    """The most local Dask worker processes ``simulate --workers`` starts: four per
    CPU core of this machine."""
    return 4 * (os.cpu_count() or 1)


def error_line(message: str) -> None:
    """Print ``error: <message>`` as one line on stderr (whitespace collapsed)."""
    sys.stderr.write(f"error: {' '.join(str(message).split())}\n")
    sys.stderr.flush()


def _then(advice: str) -> str:
    return f"; {advice}" if advice else ""


def check_count(option: str, value: int, low: int, high: int, advice: str = "") -> int:
    """``value`` as an int within [low, high]; a one-line ``ConfigError`` naming the
    option, the value, the limits and ``advice`` (what to do) otherwise."""
    if not low <= value <= high:
        bound = f">= {low:,}" if value < low else f"<= {high:,}"
        raise ConfigError(f"{option} = {value}: must be {bound}" + _then(advice))
    return int(value)


def check_number(option: str, value: float, high: float, unit: str = "",
                 advice: str = "") -> float:
    """``value`` as a float in (0, high] (``unit`` after the numbers); a one-line
    ``ConfigError`` naming the option, the value and the limit otherwise."""
    if not (math.isfinite(value) and 0 < value <= high):
        unit = f" {unit}" if unit else ""
        raise ConfigError(
            f"{option} = {format_value(float(value))}: must be > 0 and <= {high:g}{unit}"
            + _then(advice)
        )
    return float(value)


def _existing_ancestor(path: Path) -> Path:
    """The nearest ancestor of ``path`` (itself excluded) that exists."""
    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    return parent


def check_output_folder(path: Path, option: str, given: Path | None = None) -> None:
    """Refuse, before any work, a folder that cannot be made or written: ``path`` is
    an existing file, or its nearest existing ancestor is not a folder in which a file
    can be created (tried with a temporary file, removed at once). The message shows
    ``given`` (default ``path``), the option's value.

    Raises:
        ConfigError: one line naming ``option`` and its value.
    """
    shown = f"{option} = {str(given if given is not None else path)!r}"
    if path.exists():
        if not path.is_dir():
            raise ConfigError(f"{shown}: {path} is a file, not a folder; name a folder (it"
                              " is created if missing)")
        folder = path
    else:
        folder = _existing_ancestor(path)
        if not folder.is_dir():
            raise ConfigError(f"{shown}: cannot be created ({folder} is a file, not a"
                              " folder)")
    try:  # a test file: permissions alone miss read-only file systems, /proc, ...
        with tempfile.TemporaryFile(dir=folder, prefix=".photonflow-write-test-"):
            pass
    except OSError as error:
        raise ConfigError(f"{shown}: cannot write in {folder}"
                          f" ({error.strerror or error})") from None


def check_output_file(path: Path, option: str, *, overwrite: bool = True,
                      advice: str = "") -> None:
    """Refuse, before any work, an output file that could not be written: a folder,
    one whose folder cannot be made or written, or (``overwrite`` False) one that
    exists, with ``advice`` saying how to overwrite it.

    Raises:
        ConfigError: one line naming ``option`` and the path.
    """
    if path.is_dir():
        raise ConfigError(f"{option} = {str(path)!r}: is a folder; name a file")
    if path.exists() and not overwrite:
        raise ConfigError(f"{option} = {str(path)!r}: file exists" + _then(advice))
    check_output_folder(path.absolute().parent, option, given=path)


def given(context, *names: str) -> list[str]:
    """Of the command's parameters ``names`` (Python names, e.g. "energy"), those set
    on the command line or from the environment (not left at their defaults), in the
    order of ``names``; ``context`` is the command's ``typer.Context``."""
    return [name for name in names
            if getattr(context.get_parameter_source(name), "name", "DEFAULT") != "DEFAULT"]


def option_flag(context, name: str) -> str:
    """The command-line flag of the command's parameter ``name`` (e.g.
    "opening_angle" -> "--opening-angle")."""
    return next((p.opts[0] for p in context.command.params if p.name == name),
                "--" + name.replace("_", "-"))


def refuse_unused(context, names, why: str) -> None:
    """Refuse the options ``names`` (Python names) when given on the command line:
    they do not apply, and ``why`` says when they would (e.g. "only with --particle").

    Raises:
        ConfigError: one line naming the first such option and its value.
    """
    used = given(context, *names)
    if not used:
        return
    value = context.params.get(used[0])
    shown = "" if isinstance(value, bool) else f" = {format_value(value)}"
    raise ConfigError(f"{option_flag(context, used[0])}{shown}: {why}; leave it out")


def check_simulate_counts(events: int, bounces: int, workers: int | None,
                          photons: float) -> None:
    """The counts of ``simulate`` within their limits: --events in [1, MAX_EVENTS],
    --bounces in [0, MAX_BOUNCES], --workers in [1, ``max_workers()``] and --photons
    at most MAX_PHOTONS (its other checks are the source's).

    Raises:
        ConfigError: one line naming the option, the value and the limit.
    """
    check_count("--events", events, 1, MAX_EVENTS,
                "split a larger production into runs with different --seed")
    check_count("--bounces", bounces, 0, MAX_BOUNCES)
    if workers is not None:
        check_count("--workers", workers, 1, max_workers(),
                    f"this machine has {os.cpu_count()} CPU cores")
    if math.isfinite(photons) and photons > MAX_PHOTONS:
        raise ConfigError(
            f"--photons = {photons:g}: must be <= {MAX_PHOTONS:g} (a sampled event follows"
            " every photon, about 1e6 to 1e7 photons/s); use fewer photons per pulse"
        )


#: Options of ``simulate`` that only one kind of light uses, and what they are for.
_SOURCE_ONLY = {"direction": "only for a laser or diffuser source, or with --particle",
                "opening_angle": "only for a laser source (--source laser)",
                "anisotropy": "only for a diffuser source (--source diffuser)"}
_SOURCE_OPTIONS = ("position", "opening_angle", "anisotropy", "photons", "pulse_width")
_UNUSED_BY_SOURCE = {"isotropic": ("direction", "opening_angle", "anisotropy"),
                     "laser": ("anisotropy",), "diffuser": ("opening_angle",)}


def refuse_inapplicable_light(context, particle: str | None, source: str | None,
                              vertex: str) -> None:
    """Refuse ``simulate`` options given for another kind of light than the one chosen:
    source options with --particle, track options with a source, --opening-angle and
    --anisotropy with a source that has none, --direction with an isotropic source,
    --fiducial-margin with a fixed --vertex.

    Raises:
        ConfigError: one line naming the first such option.
    """
    if particle is not None:
        refuse_unused(context, _SOURCE_OPTIONS, "only for a calibration source, not with"
                      " --particle")
        if vertex != "uniform-fiducial":
            refuse_unused(context, ("fiducial_margin",), "only with --vertex uniform-fiducial")
        return
    refuse_unused(context, ("energy", "energy_range", "spectrum", "vertex", "fiducial_margin"),
                  "only with --particle")
    for name in _UNUSED_BY_SOURCE.get(source or "isotropic", ()):
        refuse_unused(context, (name,), _SOURCE_ONLY[name])


def check_benchmark_options(photons: float, repeats: int, rays: int | None,
                            bounces: int) -> None:
    """``benchmark transport``'s options within their limits (checked here, not in the
    process that runs each case): --photons in (0, MAX_PHOTONS], --repeats in [1,
    MAX_REPEATS], --rays in [1, MAX_RAYS], --bounces in [0, MAX_BOUNCES].

    Raises:
        ConfigError: one line naming the option, the value and the limit.
    """
    check_number("--photons", photons, MAX_PHOTONS)
    check_count("--repeats", repeats, 1, MAX_REPEATS)
    if rays is not None:
        check_count("--rays", rays, 1, MAX_RAYS)
    check_count("--bounces", bounces, 0, MAX_BOUNCES)


#: ``calibrate``'s write modes (as ``simulate``'s, without append).
CALIBRATION_MODES = ("create", "recreate")
#: ``calibrate`` options that only a fit uses (not ``--report``).
_FIT_OPTIONS = ("free", "init", "method", "likelihood", "rays", "bounces", "max_iterations",
                "ray_extrapolation", "jacobian_sets", "mode")


def check_calibration_options(out: Path, mode: str, rays: int, bounces: int | None,
                              max_iterations: int, jacobian_sets: int | None) -> None:
    """``calibrate``'s options, checked before any file is read or anything compiled:
    --out a writable .json file that exists only with --mode recreate, --rays in
    [MIN_CALIBRATION_RAYS, MAX_RAYS], --bounces in [0, MAX_BOUNCES], --max-iterations
    >= 1, --jacobian-sets >= 0.

    Raises:
        ConfigError: one line naming the option, the value and what to do.
    """
    if out.suffix.lower() != ".json":
        raise ConfigError(f"--out = {str(out)!r}: the calibration result is JSON (.json)")
    if mode not in CALIBRATION_MODES:
        raise ConfigError(f"--mode = {mode!r}: must be create (refuse to overwrite) or"
                          " recreate (overwrite)")
    check_output_file(out, "--out", overwrite=mode == "recreate",
                      advice="use --mode recreate to overwrite it")
    check_count("--rays", rays, MIN_CALIBRATION_RAYS, MAX_RAYS,
                "fewer rays leave the indirect light mostly ray noise" if rays < 1 << 10
                else "memory grows with the rays")
    if bounces is not None:
        check_count("--bounces", bounces, 0, MAX_BOUNCES)
    if max_iterations < 1:
        raise ConfigError(f"--max-iterations = {max_iterations}: must be >= 1")
    if jacobian_sets is not None and jacobian_sets < 0:
        raise ConfigError(f"--jacobian-sets = {jacobian_sets}: must be >= 0 (0: a fresh"
                          " set every step)")


def refuse_fit_options(context) -> None:
    """Refuse ``calibrate --report`` with an option that only a fit uses.

    Raises:
        ConfigError: one line naming the first such option.
    """
    refuse_unused(context, _FIT_OPTIONS, "only for a fit, not with --report")


def out_of_memory(error: BaseException) -> bool:
    """Whether ``error`` says the machine ran out of memory: a ``MemoryError`` (numpy)
    or an XLA ``RESOURCE_EXHAUSTED`` error (JAX)."""
    return isinstance(error, MemoryError) or (
        type(error).__name__ == "XlaRuntimeError" and "RESOURCE_EXHAUSTED" in str(error)
    )


def usage_error_line(error) -> str:
    """A click usage error (``--photons abc``, a missing option, an unknown option) as
    the text of one line, with where to look for help."""
    message = " ".join(error.format_message().split())
    context = getattr(error, "ctx", None)
    if context is not None:
        message += f" (see '{context.command_path} --help')"
    return message


def _finish(code: int) -> None:
    """Exit with ``code``; an interrupted command leaves by ``os._exit`` once its files
    are closed and its streams flushed, so that work JAX still has in flight (a
    compilation cut short) cannot crash the interpreter's shutdown."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    if code == EXIT_INTERRUPTED:
        os._exit(EXIT_INTERRUPTED)
    for signum in INTERRUPT_SIGNALS:  # the work is done: shut down without a signal death
        signal.signal(signum, signal.SIG_IGN)
    sys.exit(code)


def _quiet_interrupts(hook):
    """``sys.unraisablehook`` ``hook`` that leaves out a ``KeyboardInterrupt`` Python
    could not raise (one that landed in a garbage-collector callback): the interrupt
    itself is remembered and acted on (``interrupts.Interrupts``)."""

    def quiet(unraisable):
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            hook(unraisable)

    return quiet


def _click_exceptions():
    """The click exception classes that typer raises: those of its own copy of click
    (typer >= 0.20) or of click."""
    try:
        from typer._click import exceptions
    except ImportError:  # older typer runs on click itself
        from click import exceptions
    return exceptions


def run_console(app, prog_name: str = "photonflow") -> None:
    """Run the typer ``app`` as the console command and exit (never returns).

    A click usage error (a value that is not a number, an unknown or missing option)
    becomes one ``error:`` line with exit code 2; warnings raised while the command
    runs are shown (one ``warning:`` line each) only when it succeeds, never ahead of
    an error; SIGTERM acts as Ctrl-C, and an interrupted command exits with code 130
    (``_finish``).
    """
    import typer

    from .interrupts import terminate_as_interrupt

    interrupted = False
    exceptions = _click_exceptions()
    code = 0
    sys.unraisablehook = _quiet_interrupts(sys.unraisablehook)
    with warnings.catch_warnings(record=True) as caught, terminate_as_interrupt() as interrupts:
        try:
            try:
                code = app(prog_name=prog_name, standalone_mode=False) or 0
            finally:
                interrupts.stop_raising()  # a signal from here on: the work is done
                interrupted = interrupts.interrupted
        except exceptions.ClickException as error:
            if type(error).__name__ == "NoArgsIsHelpError":  # bare command: its help
                error.show()
            else:
                error_line(usage_error_line(error))
            code = EXIT_BAD_INPUT
        except typer.Abort as error:  # older click: Ctrl-C arrives as Abort
            code = EXIT_INTERRUPTED if isinstance(error.__context__, KeyboardInterrupt) else 1
        except KeyboardInterrupt:
            code, interrupted = EXIT_INTERRUPTED, True
    if interrupted:  # also when its exception was lost on the way
        code = EXIT_INTERRUPTED
        if not interrupts.reported:
            sys.stderr.write("interrupted\n")
    if code == 0:
        shown = set()
        for warning in caught:
            text = f"warning: {' '.join(str(warning.message).split())}"
            if text not in shown:
                shown.add(text)
                sys.stderr.write(text + "\n")
    _finish(code)
