"""The signals a flight answers (:func:`groundstation.runtime.fly._install_signals`) and, after it, the process's
end (:mod:`groundstation.cli`)."""

from __future__ import annotations

import signal

LANDING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGTSTP, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1,
                   signal.SIGUSR2, signal.SIGALRM)
"""Signals a flight lands on. By default each of the last four ends the process (Ctrl-\\ dumps core): in flight,
the modules' watchdogs cut the motors and the assembly falls."""
TOOL_SIGNALS = ("SIGUSR1", "SIGUSR2", "SIGALRM")
"""Signals tools send (log rotation, timers), not operators."""
NEVER_A_STOP = (signal.SIGHUP, signal.SIGUSR1, signal.SIGUSR2, signal.SIGALRM)
"""Signals that land but never stop the motors when repeated: no operator sends them twice to ask for a stop (a hang-up
can come twice; tools send the others repeatedly)."""
