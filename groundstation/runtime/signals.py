"""The signals a flight answers (:func:`groundstation.runtime.fly._install_signals`) and, after it, the process's
end (:mod:`groundstation.cli`)."""

from __future__ import annotations

import signal

_OTHER_ENDINGS = tuple(getattr(signal, name) for name in ("SIGPWR", "SIGXCPU", "SIGVTALRM", "SIGPROF", "SIGIO",
                                                           "SIGSTKFLT", "SIGABRT", "SIGTRAP", "SIGSYS")
                       if hasattr(signal, name)) + \
    tuple(signal.Signals(s) if s in (signal.SIGRTMIN, signal.SIGRTMAX) else s
          for s in range(signal.SIGRTMIN, signal.SIGRTMAX + 1))
"""Every other signal whose default action ends the process, but the hardware faults of its own code (SIGSEGV,
SIGBUS, SIGFPE, SIGILL: a handler returns to the faulting instruction, which faults again, for good): a UPS's power
failure, the CPU-time limit (``ulimit -t``, systemd's ``LimitCPU=``: SIGXCPU, once a second until SIGKILL),
profilers' timers, the real-time signals, SIGABRT (systemd's ``WatchdogSec=``, ``kill -ABRT``; a library's own
abort() still ends the process: abort() raises it again once the handler returns), SIGTRAP and SIGSYS (sent with
kill; campaign 28: each ended ``fly`` 0.8-0.94 m up). Unhandled, each ended ``fly`` mid-air (hostile campaign: 0.94 m
up, no summary, the log "no end of flight")."""
LANDING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGTSTP, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1,
                   signal.SIGUSR2, signal.SIGALRM, *_OTHER_ENDINGS)
"""Signals a flight lands on. By default each after the first four ends the process (Ctrl-\\ dumps core): in
flight, the modules' watchdogs cut the motors and the assembly falls."""
NEVER_A_STOP = (signal.SIGHUP, signal.SIGUSR1, signal.SIGUSR2, signal.SIGALRM, *_OTHER_ENDINGS)
"""Signals that land but never stop the motors when repeated: no operator sends them twice to ask for a stop (a hang-up
can come twice; tools, timers and the kernel send the others repeatedly)."""


def signal_name(signum: int) -> str:
    """``SIGTERM``, ``SIGRTMIN+3``: the real-time signals between the first and the last have no name of their
    own (:class:`signal.Signals` has none for them)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"SIGRTMIN+{signum - signal.SIGRTMIN}"


TOOL_SIGNALS = tuple(signal_name(s) for s in (signal.SIGUSR1, signal.SIGUSR2, signal.SIGALRM, *_OTHER_ENDINGS))
"""Signals tools, timers and the kernel send, not operators."""
