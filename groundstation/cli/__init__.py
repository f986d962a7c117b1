"""Command-line interface: a thin layer over library functions.

Every command is a function a test can call through click's runner. Errors raised on purpose by the package
(:class:`~groundstation.errors.GroundstationError`) and click's own usage errors become one line on stderr and a
non-zero exit code: 2 for bad input, 1 for a result that failed (e.g. an infeasible design, modules that cannot
be reached or refuse to arm), 130 on Ctrl-C.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import signal
import sys
import threading

import click

from groundstation import __version__
from groundstation.cli.design_cmd import design_command
from groundstation.cli.enumerate_cmd import enumerate_command
from groundstation.cli.fly_cmd import fly_command, log_group, mocap_bridge_command, sim_peer_command
from groundstation.cli.mocap_cmd import mocap_key_command
from groundstation.cli.optimize_cmd import optimize_command
from groundstation.cli.params_cmd import params_command
from groundstation.cli.replay_cmd import replay_command
from groundstation.cli.simulate_cmd import simulate_command
from groundstation.errors import BackendError, GroundstationError
from groundstation.output import StdoutError, hold_standard_descriptors, stdout_lost
from groundstation.runtime.signals import LANDING_SIGNALS

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="groundstation")
def cli() -> None:
    """Design, simulate and fly modular aerial systems (downwash-aware configuration optimization)."""


cli.add_command(enumerate_command)
cli.add_command(optimize_command)
cli.add_command(design_command)
cli.add_command(simulate_command)
cli.add_command(fly_command)
cli.add_command(log_group)
cli.add_command(mocap_bridge_command)
cli.add_command(mocap_key_command)
cli.add_command(sim_peer_command)
cli.add_command(params_command)
cli.add_command(replay_command)


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``groundstation`` and ``python -m groundstation``."""
    if argv is None:
        hold_standard_descriptors()
    # cflib logs every link problem as a warning with a traceback; our errors name the module and its link.
    logging.getLogger("cflib").setLevel(logging.ERROR)
    # A command may leave handlers for the process's end (``fly``: a signal after the flight ends the process with
    # its status); called in-process (``argv`` given: a test, a script), the caller's are put back.
    handlers = {s: signal.getsignal(s) for s in signal.valid_signals()} if argv is not None else {}
    _terminate_as_interrupt()
    try:
        rv = _run(argv)
    finally:
        for s, h in handlers.items():
            if signal.getsignal(s) is not h:
                signal.signal(s, h)
    if argv is None:
        try:  # what was printed into the buffer reaches stdout here, or fails here
            sys.stdout.flush()
        except StdoutError as exc:
            _say_not_printed(exc)
            rv = rv or EXIT_FAILED
        # The command's work is done: a signal while the interpreter exits must not change its status. Late in
        # its exit Python puts the default handlers back (not where they are ignored), and a SIGTERM there ended
        # a finished flight 143 after its summary said "done" (hostile campaign). Blocking them would not do: Zenoh's
        # threads would take them.
        for s in LANDING_SIGNALS:
            signal.signal(s, signal.SIG_IGN)
    sys.exit(rv)


ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
_ended_by: list[int] = []
"""The ending signal that interrupted the command, if one did."""


def _terminate_as_interrupt() -> None:
    """SIGTERM and a hang-up end a command as Ctrl-C does, unless ignored (``nohup``): its work stops where it
    is interruptible, what it was writing is removed or finalized, worker processes end with it, and the exit
    status says which signal (128 + its number). By default they killed the process where it stood: ``log
    recover`` left a partial copy that its retry then refused to overwrite, and ``design`` left a worker running
    (hostile campaign 30). ``fly`` puts its own handlers over these (it lands)."""

    _ended_by.clear()  # an earlier command of this process (called in-process) is not this one

    def handler(signum, frame):
        _ended_by.append(signum)
        interrupt = signal.getsignal(signal.SIGINT)
        if callable(interrupt):  # Python's (raises KeyboardInterrupt) or a solver's (sets its stop flag)
            interrupt(signal.SIGINT, frame)
        else:  # Ctrl-C ignored (a background job of a script): the signal still ends the command
            raise KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():
        return  # called in-process from another thread (a test, a script): signals are the main thread's business
    for s in ENDING_SIGNALS:
        if signal.getsignal(s) == signal.SIG_DFL:
            signal.signal(s, handler)


def _interrupted() -> int:
    """Say the command was interrupted (by which signal, if not Ctrl-C); its exit status."""
    if _ended_by:
        signum = _ended_by[-1]
        click.echo(f"groundstation: interrupted ({signal.Signals(signum).name})", err=True)
        return 128 + signum
    click.echo("groundstation: interrupted", err=True)
    return EXIT_INTERRUPTED


def _run(argv: list[str] | None) -> int:
    """The command's exit status."""
    try:
        rv = cli.main(args=argv, prog_name="groundstation", standalone_mode=False)
    except click.exceptions.NoArgsIsHelpError as exc:  # bare command: show help, like click does
        try:
            click.echo(exc.ctx.get_help() if exc.ctx else str(exc))
        except StdoutError as lost:  # raised in this handler, the one beside it would not catch it
            _say_not_printed(lost)
            return EXIT_FAILED
        return 0
    except click.UsageError as exc:
        hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx and exc.ctx.parent else ""  # 'log recover' too
        click.echo(f"groundstation: error: {exc.format_message()}{hint}", err=True)
        return EXIT_BAD_INPUT
    except (click.exceptions.Abort, KeyboardInterrupt):
        return _interrupted()
    except BackendError as exc:
        click.echo(f"groundstation: error: {exc}", err=True)
        return EXIT_FAILED
    except GroundstationError as exc:
        click.echo(f"groundstation: error: {exc}", err=True)
        return EXIT_BAD_INPUT
    except StdoutError as exc:  # any other OSError is a fault to see whole (a command's files: output.writing)
        _say_not_printed(exc)
        return EXIT_FAILED
    return rv if isinstance(rv, int) else 0


def _say_not_printed(exc: StdoutError) -> None:
    """One line on stderr: what the command printed did not reach stdout (a full device, closed, a pipe gone)."""
    if exc.errno != errno.EPIPE:  # a reader that went (`| head`) chose to stop: quiet, as click has it
        with contextlib.suppress(OSError):  # stderr may be as broken: then the exit status says it
            click.echo(f"groundstation: error: cannot print the output ({exc.strerror})", err=True)
    stdout_lost()
