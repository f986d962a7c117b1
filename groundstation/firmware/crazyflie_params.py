"""Reading and writing a Crazyflie module's parameters through cflib's ``Crazyflie`` class (TOC, param service).

This opens a full cflib connection (table-of-contents download, all parameter values), which the flight's own
link (raw link drivers, :mod:`groundstation.backends.crazyflie`) avoids; so it runs before the flight, never in
it. Every wait is bounded by ``timeout``.
"""

from __future__ import annotations

import threading
from pathlib import Path

from cflib.crazyflie import Crazyflie

from groundstation.backends.crazyflie import ensure_drivers
from groundstation.firmware.params import ParamCheck, matches


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


def check_crazyflie(uri: str, module: int, wanted: dict[str, float], apply: bool = False,
                    timeout: float = 5.0, toc_cache: Path | None = None) -> list[ParamCheck]:
    """Compare module ``module``'s parameters at ``uri`` with ``wanted``; with ``apply``, write the ones that
    differ and read them back. ``toc_cache`` keeps downloaded tables of contents between runs (a directory)."""
    ensure_drivers()
    cache = None
    if toc_cache is not None:
        toc_cache.mkdir(parents=True, exist_ok=True)
        cache = str(toc_cache)
    cf = Crazyflie(rw_cache=cache)
    ready = threading.Event()
    failure: list[str] = []
    cf.fully_connected.add_callback(lambda _uri: ready.set())
    cf.connection_failed.add_callback(lambda _uri, msg: (failure.append(str(msg).splitlines()[0]), ready.set()))
    values = _Values()
    cf.open_link(uri)
    try:
        if not ready.wait(timeout) or failure:
            why = failure[0] if failure else f"no answer within {timeout:g} s"
            return [ParamCheck(module, uri, n, v, None, note=why) for n, v in wanted.items()]
        checks = []
        for name, expected in wanted.items():
            element = cf.param.toc.get_element_by_complete_name(name)
            if element is None:
                checks.append(ParamCheck(module, uri, name, expected, None, note="not in the module's parameters"))
                continue
            group, short = name.split(".")
            actual = float(cf.param.values[group][short])
            written = False
            if apply and not matches(actual, expected):
                cf.param.add_update_callback(group=group, name=short, cb=values.on_update)
                seen = values.count(name)
                cf.param.set_value(name, expected)  # the module echoes the value it applied
                echoed = values.wait_update(name, seen, timeout)
                cf.param.request_param_update(name)  # and a fresh read confirms it
                read = values.wait_update(name, seen + 1, timeout) if echoed is not None else None
                actual, written = (float(read) if read is not None else None), True
            checks.append(ParamCheck(module, uri, name, expected, actual, written=written,
                                     note="" if actual is not None else f"no answer within {timeout:g} s"))
        return checks
    finally:
        cf.close_link()
