"""Reading and writing a Crazyflie module's parameters through cflib's ``Crazyflie`` class (TOC, param service).

This opens a full cflib connection (table-of-contents download, all parameter values), which the flight's own
link (raw link drivers, :mod:`groundstation.backends.crazyflie`) avoids; so it runs before the flight, never in
it. Every wait is bounded by ``timeout``; unanswered requests are repeated, and a connection that does not come up
is tried ``ATTEMPTS`` times. Written persistent parameters (``supervisor.tmblChckEn``) are also
stored in the module's EEPROM: an emergency stop locks a module until it is rebooted, and a reboot would bring
back the stock value. Read-only parameters (``motorApp.version``) are never written: a wrong one means the wrong
firmware is flashed.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from cflib.crazyflie import Crazyflie
from cflib.crazyflie.param import ParamTocElement
from cflib.crtp.crtpstack import CRTPPacket
from cflib.crtp.udpdriver import UdpDriver

from groundstation.backends import crtp_wire as wire
from groundstation.backends.crazyflie import ensure_drivers
from groundstation.firmware.params import ParamCheck, held_anyway, matches, outside_type

ATTEMPTS = 5
"""Connections tried per module."""
FOREIGN_PACKETS = 10
"""More packets than this that break cflib's callbacks end a connection attempt: the link is not a Crazyflie's (a
PX4 module answered with thousands), not a glitch."""
FIRST_ANSWER_S = 1.0
"""How long a connection attempt waits for the module's first packet, s."""


class _Values:
    """Parameter values as cflib reports them (its callbacks run on its receive thread)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._seen: dict[str, tuple[int, str]] = {}

    def on_update(self, name: str, value: str) -> None:
        with self._cond:
            count = self._seen.get(name, (0, ""))[0]
            self._seen[name] = (count + 1, value)
            self._cond.notify_all()

    def count(self, name: str) -> int:
        with self._cond:
            return self._seen.get(name, (0, ""))[0]

    def wait_update(self, name: str, after: int, timeout: float) -> str | None:
        """The value of the first update of ``name`` after ``after`` updates, or None after ``timeout`` s."""
        with self._cond:
            if self._cond.wait_for(lambda: self._seen.get(name, (0, ""))[0] > after, timeout):
                return self._seen[name][1]
            return None


class _RepeatingCrazyflie(Crazyflie):
    """cflib's ``Crazyflie`` repeating unanswered requests from the very first one.

    cflib repeats a request only where the link driver asks for it (a radio without safelink); its UDP driver
    assumes loopback never loses a packet. A relayed or bridged link can: repeat there too (the requests are reads,
    and writes of the same value, so a repeat is harmless). The flag must be set before the connection set-up's
    first request (the platform version), which ``open_link`` sends before it returns: a lost one was never repeated
    and the connection hung (cflib 0.1.34's ``_start_connection_setup``)."""

    def _start_connection_setup(self):
        self.link.needs_resending = True
        self.opened_link = self.link
        """The link driver (cflib drops ``link`` on a link error; its packet thread may still wait on it)."""
        super()._start_connection_setup()

    def _no_answer_do_retry(self, pk, pattern):
        # A repeat's timer can fire while close_link sets the link to None: cflib 0.1.34's send_packet checks the
        # link and then uses it, and the timer thread's traceback ("'NoneType' object has no attribute
        # 'send_packet'") reached the operator's terminal. A closed link has nothing left to repeat.
        if self.link is not None:
            with contextlib.suppress(AttributeError):  # closed between that check and cflib's own use of it
                super()._no_answer_do_retry(pk, pattern)


class _Unparsed(logging.Filter):
    """Counts, and keeps off the terminal, the tracebacks cflib logs when a packet breaks one of its callbacks:
    a link that is not a Crazyflie's (a PX4 module speaking MAVLink answered with thousands of them). Counted per
    thread, since modules are checked at once: cflib logs them on the connection's own packet thread
    (``Crazyflie.incoming``)."""

    def __init__(self) -> None:
        super().__init__()
        self._counts: dict[int | None, int] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if message.startswith("Exception while doing callback"):
            self._counts[record.thread] = self._counts.get(record.thread, 0) + 1
            return False
        # A link that does not open (a host its driver cannot resolve): the check's one line names it; cflib's
        # traceback of it, once per attempt, filled the terminal (121 lines: hostile campaign 34).
        return not message.startswith("Couldn't load link driver")

    def count(self, cf: Crazyflie) -> int:
        """How many came from ``cf``'s connection."""
        return self._counts.get(cf.incoming.ident, 0)


_UNPARSED = _Unparsed()
_UNPARSED_USERS = [0]
_UNPARSED_LOCK = threading.Lock()


@contextlib.contextmanager
def _counting_unparsed():
    """:data:`_UNPARSED` on cflib's logger while any module's check runs (one filter for every thread)."""
    log = logging.getLogger("cflib.crazyflie")
    with _UNPARSED_LOCK:
        if _UNPARSED_USERS[0] == 0:
            log.addFilter(_UNPARSED)
        _UNPARSED_USERS[0] += 1
    try:
        yield _UNPARSED
    finally:
        with _UNPARSED_LOCK:
            _UNPARSED_USERS[0] -= 1
            if _UNPARSED_USERS[0] == 0:
                log.removeFilter(_UNPARSED)


@dataclass(frozen=True)
class _Attempt:
    """One connection attempt's outcome."""

    cf: Crazyflie | None
    """Connected (tables of contents and values downloaded), or None."""
    why: str = ""
    """Why not."""
    again: bool = False
    """Worth another attempt: nothing answered (a lost first packet), or cflib gave up on the link. Not when the
    module answered and its parameters never came (a module without the parameter service: five more waits of the
    whole timeout took 25 s a module), nor when what answered is not a Crazyflie."""
    unparsed: int = 0
    """Packets that broke cflib's callbacks on this attempt."""
    slow: bool = False
    """The module answered but its parameters did not all come: one more attempt is worth it (on a link losing 5 %
    a table-of-contents download can stall past the timeout; it failed the fault table's lossy-link row once in
    four suite runs), not five."""


def _connect(uri: str, timeout: float, cache: str | None, unparsed: _Unparsed) -> _Attempt:
    """Connect to ``uri``. The set-up's first request (the protocol version) is one cflib never repeats: without an
    answer within ``FIRST_ANSWER_S`` the attempt ends early, so a lost packet costs a second, not the whole timeout.
    So do more than ``FOREIGN_PACKETS`` that cflib cannot parse (the link answers with what is not CRTP: waiting
    for a table of contents that never comes took 5 s a module)."""
    cf = _RepeatingCrazyflie(rw_cache=cache)
    ready, woken, answered = threading.Event(), threading.Event(), threading.Event()
    failure: list[str] = []
    cf.link_established.add_callback(lambda _uri: (answered.set(), woken.set()))
    cf.fully_connected.add_callback(lambda _uri: ready.set())
    cf.connection_failed.add_callback(lambda _uri, msg: (failure.append(str(msg).splitlines()[0]), ready.set(),
                                                         woken.set()))
    cf.open_link(uri)
    deadline = time.monotonic() + timeout
    if woken.wait(min(FIRST_ANSWER_S, timeout)):
        while not ready.wait(0.05) and unparsed.count(cf) <= FOREIGN_PACKETS and time.monotonic() < deadline:
            pass
    if ready.is_set() and not failure:
        # cflib pings every link it connects 10 times a second (link statistics, 0.1.34). A module answers to
        # where its last datagram came from, so each ping drew replies away from a backend already streaming on
        # another socket; and a ping sent while the link closed printed a thread's traceback ("Bad file
        # descriptor", then "cannot join current thread") on the pilot's terminal.
        cf.link_statistics.stop()
        return _Attempt(cf)
    foreign = unparsed.count(cf)
    _close(cf)
    if failure:
        return _Attempt(None, failure[0], again=not foreign, unparsed=foreign)
    if answered.is_set():
        return _Attempt(None, f"it answered, but its parameters did not arrive within {timeout:g} s",
                        unparsed=foreign, slow=True)
    return _Attempt(None, f"no answer within {FIRST_ANSWER_S:g} s", again=True)


def _close(cf: Crazyflie) -> None:
    """``close_link`` without its two waits of up to a second each: cflib's packet thread sleeps in a 1 s receive
    and its UDP driver's receive thread in a 1 s socket timeout when the module sends nothing unprompted (the motor
    app only answers commands), and closing joins both. Wake them first (cflib 0.1.34 internals: ``incoming``, the
    driver's ``in_queue``, where a None packet is skipped, and the UDP receive thread's stop flag ``_sp``, set before
    a version request whose answer ends its receive)."""
    cf.link_statistics.stop()  # no ping after the close (see _connect)
    for timer in list(cf._answer_patterns.values()):  # no repeat after the close (see _no_answer_do_retry)
        if timer is not None:
            timer.cancel()
    cf.incoming.stop()
    # After a link error cflib has dropped ``link``, but its packet thread may still wait on the old driver's queue
    # (1 s per attempt on a module that is off: 10 s for two modules).
    in_queue = getattr(cf.link or getattr(cf, "opened_link", None), "in_queue", None)
    if in_queue is not None:
        in_queue.put(None)
    receiver = getattr(cf.link, "_thread", None)
    if isinstance(cf.link, UdpDriver) and receiver is not None and hasattr(receiver, "_sp"):
        receiver._sp = True
        with contextlib.suppress(Exception):
            cf.link.send_packet(CRTPPacket(wire.VERSION_HEADER, bytes([wire.GET_PROTOCOL_VERSION])))
        # A module that is off answers nothing: shutting the socket's receive side returns the blocked receive at
        # once (each of the 5 attempts on a silent module waited out the 1 s timeout: 10 s for two modules).
        with contextlib.suppress(OSError):
            cf.link.socket.shutdown(socket.SHUT_RD)
    cf.close_link()


def _stored_value(cf: Crazyflie, name: str, timeout: float) -> float | None:
    """The value a persistent parameter has stored in the module's EEPROM, or None (not stored, no answer)."""
    done = threading.Event()
    result: list = []
    cf.param.persistent_get_state(name, lambda _name, state: (result.append(state), done.set()))
    if not done.wait(timeout) or not result or result[0] is None or not result[0].is_stored:
        return None
    return float(result[0].stored_value)


def _store(cf: Crazyflie, name: str, timeout: float) -> bool:
    """Store a persistent parameter's current value in the module's EEPROM; True once the module confirms."""
    done = threading.Event()
    result: list[bool] = []
    cf.param.persistent_store(name, lambda _name, ok: (result.append(ok), done.set()))
    return done.wait(timeout) and result == [True]


def check_crazyflie(uri: str, module: int, wanted: dict[str, float], apply: bool = False,
                    timeout: float = 5.0, toc_cache: Path | None = None) -> list[ParamCheck]:
    """Compare module ``module``'s parameters at ``uri`` with ``wanted``; with ``apply``, write the ones that
    differ (storing persistent ones) and read them back. ``toc_cache`` keeps downloaded tables of contents
    between runs (a directory)."""
    ensure_drivers()
    cache = None
    if toc_cache is not None:
        toc_cache.mkdir(parents=True, exist_ok=True)
        cache = str(toc_cache)
    with _counting_unparsed() as unparsed:
        tried, slow = 0, 0
        while tried < ATTEMPTS:
            tried += 1
            attempt = _connect(uri, timeout, cache, unparsed)
            slow += attempt.slow
            if not (attempt.again or (attempt.slow and slow < 2)):
                break
    cf, why = attempt.cf, attempt.why
    if cf is None:
        if attempt.unparsed:
            why = (f"not a Crazyflie on this link: it sends packets cflib cannot parse ({attempt.unparsed}; a "
                   f"MAVLink module?)")
        elif tried > 1:
            why += f" ({tried} attempts)"
        return [ParamCheck(module, uri, n, v, None, note=why, unreachable=True) for n, v in wanted.items()]
    values = _Values()
    try:
        checks = []
        for name, expected in wanted.items():
            element = cf.param.toc.get_element_by_complete_name(name)
            if element is None:
                checks.append(ParamCheck(module, uri, name, expected, None, note="not in the module's parameters"))
                continue
            group, short = name.split(".")
            actual = float(cf.param.values[group][short])
            if why := outside_type(expected, element.ctype):  # whether or not the module's value matches it
                checks.append(ParamCheck(module, uri, name, expected, None, note=held_anyway(why, actual)))
                continue
            if matches(actual, expected) and element.is_persistent():
                # Right in RAM is not enough: a value set but never stored (by hand, or an interrupted apply) is
                # lost at the reboot an emergency stop requires. Store it (only then: EEPROM wears) with --apply.
                stored = _stored_value(cf, name, timeout)
                if (stored is not None and matches(stored, expected)) or (apply and _store(cf, name, timeout)):
                    checks.append(ParamCheck(module, uri, name, expected, actual, stored=True))
                else:
                    back = "the stock value" if stored is None else f"{stored:g}"
                    checks.append(ParamCheck(module, uri, name, expected, None,
                                             note=f"right in RAM but not stored: a reboot brings {back} back"))
                continue
            if not apply or matches(actual, expected):
                checks.append(ParamCheck(module, uri, name, expected, actual))
                continue
            if element.access == ParamTocElement.RO_ACCESS:
                checks.append(ParamCheck(module, uri, name, expected, actual,
                                         note="read-only: flash the firmware that has it right"))
                continue
            cf.param.add_update_callback(group=group, name=short, cb=values.on_update)
            seen = values.count(name)
            cf.param.set_value(name, expected)  # the module echoes the value it applied
            echoed = values.wait_update(name, seen, timeout)
            cf.param.request_param_update(name)  # and a fresh read confirms it
            read = values.wait_update(name, seen + 1, timeout) if echoed is not None else None
            actual = float(read) if read is not None else None
            stored = actual is not None and element.is_persistent() and _store(cf, name, timeout)
            note = "" if actual is not None else f"no answer within {timeout:g} s"
            if actual is not None and element.is_persistent() and not stored:
                note = "written but not stored: a reboot brings the old value back"
            checks.append(ParamCheck(module, uri, name, expected, actual, written=True, stored=stored, note=note))
        return checks
    finally:
        _close(cf)


TOC_CACHE = ".cflib-toc"
"""Directory (in the flight's log directory) keeping cflib's parameter tables of contents between runs."""


def check_module(uri: str, module: int, wanted: dict[str, float], apply: bool,
                 cache_dir: Path | None) -> list[ParamCheck]:
    """:func:`check_crazyflie` as the backend table calls it, the tables of contents kept in ``cache_dir``."""
    return check_crazyflie(uri, module, wanted, apply, toc_cache=cache_dir / TOC_CACHE if cache_dir else None)
