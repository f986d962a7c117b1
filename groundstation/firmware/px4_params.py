"""Reading and writing a PX4 module's parameters over MAVLink (PARAM_REQUEST_READ / PARAM_SET -> PARAM_VALUE).

Runs on its own pymavlink connection before the flight; every wait is bounded by ``timeout`` and a request that
goes unanswered is repeated (MAVLink over UDP or a radio may drop a packet).
"""

from __future__ import annotations

import time
from pathlib import Path

from pymavlink import mavutil

from groundstation.backends import mavlink_wire as mw
from groundstation.firmware.params import ParamCheck, held_anyway, matches, outside_type

mav = mavutil.mavlink
ATTEMPTS = 3
HEARTBEAT_WAIT_S = 2.5
"""How long to wait for a module's first heartbeat, s. PX4 sends one per second, so a 1 s window races its phase
(CI: "no heartbeat within 1 s" from a live module); 2.5 s covers two heartbeats and a late one."""


def _vehicle(conn, timeout: float) -> tuple[int, int] | None:
    """(system, component) of the autopilot on ``conn``, from its heartbeat."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        msg = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=min(0.2, max(end - time.monotonic(), 0.0)))
        if msg is not None and msg.type != mav.MAV_TYPE_GCS and msg.autopilot != mav.MAV_AUTOPILOT_INVALID:
            return msg.get_srcSystem(), msg.get_srcComponent()
    return None


def _param_value(conn, name: str, send, timeout: float):
    """Send (``send()``) until the PARAM_VALUE for ``name`` arrives; None after ``ATTEMPTS`` x ``timeout``."""
    for _ in range(ATTEMPTS):
        send()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=max(end - time.monotonic(), 0.0))
            if msg is not None and msg.param_id == name:
                return msg
    return None


def check_px4(link: str, module: int, wanted: dict[str, float], apply: bool = False,
              timeout: float = 1.0, heartbeat_timeout: float = HEARTBEAT_WAIT_S) -> list[ParamCheck]:
    """Compare module ``module``'s parameters at ``link`` (a pymavlink connection string) with ``wanted``; with
    ``apply``, write the ones that differ (with the type the module reports) and read them back. ``timeout`` bounds
    each parameter exchange, ``heartbeat_timeout`` the wait for the module's first heartbeat, s."""
    try:
        conn = mavutil.mavlink_connection(link, source_system=mw.GCS_SYSTEM_ID, source_component=mw.GCS_COMPONENT_ID)
    except Exception as exc:  # pymavlink raises per transport
        return [ParamCheck(module, link, n, v, None, note=f"cannot open: {exc}", unreachable=True)
                for n, v in wanted.items()]
    try:
        target = _vehicle(conn, heartbeat_timeout)
        if target is None:
            return [ParamCheck(module, link, n, v, None, note=f"no heartbeat within {heartbeat_timeout:g} s",
                               unreachable=True) for n, v in wanted.items()]
        system, component = target
        checks = []
        for name, expected in wanted.items():
            pid = name.encode()

            def read(pid=pid):
                conn.mav.param_request_read_send(system, component, pid, -1)

            msg = _param_value(conn, name, read, timeout)
            if msg is None:
                checks.append(ParamCheck(module, link, name, expected, None, note="no such parameter, or no answer"))
                continue
            actual = mw.param_from_wire(msg.param_value, msg.param_type)
            written = False
            if why := outside_type(expected, mw.PARAM_CTYPES.get(msg.param_type, "")):
                checks.append(ParamCheck(module, link, name, expected, None, note=held_anyway(why, actual)))
                continue
            if apply and not matches(actual, expected):
                kind = msg.param_type

                def write(pid=pid, kind=kind, value=expected):
                    conn.mav.param_set_send(system, component, pid, mw.param_to_wire(value, kind), kind)

                echo = _param_value(conn, name, write, timeout)
                msg = _param_value(conn, name, read, timeout) if echo is not None else None
                actual = mw.param_from_wire(msg.param_value, msg.param_type) if msg is not None else None
                written = True
            checks.append(ParamCheck(module, link, name, expected, actual, written=written,
                                     note="" if actual is not None else "no answer to the write"))
        return checks
    finally:
        conn.close()


def check_module(link: str, module: int, wanted: dict[str, float], apply: bool,
                 cache_dir: Path | None) -> list[ParamCheck]:
    """:func:`check_px4` as the backend table calls it. ``cache_dir`` is not used: PX4 answers each parameter by
    name, there is no table of contents to keep."""
    return check_px4(link, module, wanted, apply)


def pwm_params(section) -> dict[str, float]:
    """The PWM range a flight config's ``backend`` section assumes (``pwm_min``, ``pwm_max``, us)."""
    return {"PWM_MAIN_MIN": float(section.pwm_min), "PWM_MAIN_MAX": float(section.pwm_max)}
