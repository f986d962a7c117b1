"""Command-line interface: a thin layer over library functions.

Every command is a function a test can call through click's runner. Errors raised on purpose by the package
(:class:`~groundstation.errors.GroundstationError`) and click's own usage errors become one line on stderr and a
non-zero exit code: 2 for bad input, 1 for a result that failed (e.g. an infeasible design, modules that cannot
be reached or refuse to arm), 130 on Ctrl-C.
"""

from __future__ import annotations

import logging
import sys

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
    # cflib logs every link problem as a warning with a traceback; our errors name the module and its link.
    logging.getLogger("cflib").setLevel(logging.ERROR)
    try:
        rv = cli.main(args=argv, prog_name="groundstation", standalone_mode=False)
    except click.exceptions.NoArgsIsHelpError as exc:  # bare command: show help, like click does
        click.echo(exc.ctx.get_help() if exc.ctx else str(exc))
        sys.exit(0)
    except click.UsageError as exc:
        hint = f" (see 'groundstation {exc.ctx.info_name} --help')" if exc.ctx and exc.ctx.parent else ""
        click.echo(f"groundstation: error: {exc.format_message()}{hint}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    except click.exceptions.Abort:
        click.echo("groundstation: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except KeyboardInterrupt:
        click.echo("groundstation: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except BackendError as exc:
        click.echo(f"groundstation: error: {exc}", err=True)
        sys.exit(EXIT_FAILED)
    except GroundstationError as exc:
        click.echo(f"groundstation: error: {exc}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    sys.exit(rv if isinstance(rv, int) else 0)
