"""The ``groundstation`` command's entry point, loading nothing but the standard library before the CLI.

The CLI's own imports (click, rich, the commands) take a few tenths of a second, and a Ctrl-C meanwhile raised
``KeyboardInterrupt`` out of whatever module was loading: a 28-line traceback (hostile campaign 30). Caught here,
it ends the command as an interrupt later does (:func:`groundstation.cli.main`): one line, exit 130."""

import sys

EXIT_INTERRUPTED = 130
"""Exit status of an interrupted command (``groundstation.cli.EXIT_INTERRUPTED``, which cannot be imported before
the guard)."""


def main() -> None:
    try:
        from groundstation.cli import main as run
    except KeyboardInterrupt:
        sys.stderr.write("groundstation: interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    run()
