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

import threading
from pathlib import Path

from cflib.crazyflie import Crazyflie
from cflib.crazyflie.param import ParamTocElement

from groundstation.backends.crazyflie import ensure_drivers
from groundstation.firmware.params import ParamCheck, matches

ATTEMPTS = 3


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


def _connect(uri: str, timeout: float, cache: str | None) -> tuple[Crazyflie | None, str]:
    """A fully connected ``Crazyflie`` (TOC and values downloaded), or None and why not."""
    cf = Crazyflie(rw_cache=cache)
    ready = threading.Event()
    failure: list[str] = []
    cf.fully_connected.add_callback(lambda _uri: ready.set())
    cf.connection_failed.add_callback(lambda _uri, msg: (failure.append(str(msg).splitlines()[0]), ready.set()))
    cf.open_link(uri)
    if cf.link is not None:
        # cflib repeats an unanswered request only where the link driver asks for it (a radio without safelink);
        # its UDP driver assumes loopback never loses a packet. A relayed or bridged link can: repeat there too
        # (the requests are reads, and writes of the same value, so a repeat is harmless).
        cf.link.needs_resending = True
    if ready.wait(timeout) and not failure:
        return cf, ""
    cf.close_link()
    return None, failure[0] if failure else f"no answer within {timeout:g} s"


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
    cf, why = None, ""
    for _ in range(ATTEMPTS):
        cf, why = _connect(uri, timeout, cache)
        if cf is not None:
            break
    if cf is None:
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
        cf.close_link()


TOC_CACHE = ".cflib-toc"
"""Directory (in the flight's log directory) keeping cflib's parameter tables of contents between runs."""


def check_module(uri: str, module: int, wanted: dict[str, float], apply: bool,
                 cache_dir: Path | None) -> list[ParamCheck]:
    """:func:`check_crazyflie` as the backend table calls it, the tables of contents kept in ``cache_dir``."""
    return check_crazyflie(uri, module, wanted, apply, toc_cache=cache_dir / TOC_CACHE if cache_dir else None)
