"""Crazyflie modules over cflib's CRTP link drivers: one link per module, motor commands on the app channel.

Each module runs the motor app described in ``firmware_params/README.md``; :mod:`groundstation.backends.crtp_wire`
holds the packets. A link is a cflib link driver chosen by URI (``radio://0/80/2M/E7E7E7E701`` for a Crazyradio,
``udp://127.0.0.1:19850`` for a simulated module), used directly rather than through ``cflib.crazyflie.Crazyflie``:
the control loop needs one small packet per module per period and nothing of the connection set-up (TOC
download, parameters) on its path. Sending is a socket or USB write on the caller's thread; replies are
collected by cflib's receive thread and drained without blocking by :meth:`CrazyflieBackend.telemetry`.

Safety at this edge: commands are bounded (``applied_command``) and carry the armed flag, so a module ignores
them until armed; :meth:`emergency_stop` sends the supervisor's emergency stop and a disarmed zero command to
every module; a module whose state has not arrived for ``link_timeout`` makes ``link_ok`` False, and the flight
stops. The module app has its own staleness timeout, so a ground station that dies stops the motors too.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from cflib.crtp.crtpstack import CRTPPacket

from groundstation.backends import crtp_wire as wire
from groundstation.backends.base import PreflightReport, Telemetry, applied_command, body_rate
from groundstation.errors import GroundstationError


class CrazyflieLinkError(GroundstationError):
    """A module's link could not be opened."""


_drivers_ready = threading.Lock()
_drivers_initialized = False


def ensure_drivers() -> None:
    """Initialise cflib's link drivers once per process (every cflib connection needs them)."""
    global _drivers_initialized
    import cflib.crtp

    with _drivers_ready:
        if not _drivers_initialized:
            cflib.crtp.init_drivers()
            _drivers_initialized = True


def _link_driver(uri: str, on_error):
    """An open cflib link driver for ``uri``."""
    import cflib.crtp

    ensure_drivers()
    try:
        driver = cflib.crtp.get_link_driver(uri, link_error_callback=on_error)
    except Exception as exc:  # driver-specific errors (no dongle, bad address)
        raise CrazyflieLinkError(f"cannot open {uri}: {exc}") from None
    if driver is None:
        raise CrazyflieLinkError(f"cannot open {uri}: no cflib driver accepts this URI")
    return driver


@dataclass(frozen=True)
class CrazyflieSettings:
    link_timeout: float = 0.1
    """A module whose state is older than this is lost, s."""
    min_battery_v: float = 3.5
    """Preflight: lowest acceptable battery voltage, V (per cell of a 1S module)."""
    preflight_timeout: float = 1.0
    """Preflight: how long to wait for every module's state, s."""


class CrazyflieBackend:
    """``n`` Crazyflie modules of one assembly, in assembly order (module i drives rotors 4i..4i+3)."""

    def __init__(self, uris: list[str] | tuple[str, ...], u_max: float, module_rotations: np.ndarray,
                 settings: CrazyflieSettings | None = None, clock=time.monotonic) -> None:
        if len(uris) != len(module_rotations):
            raise ValueError(f"{len(uris)} links for {len(module_rotations)} modules")
        self.uris = tuple(uris)
        self.u_max = u_max
        self.settings = settings or CrazyflieSettings()
        self._rotations = np.asarray(module_rotations, float)
        self._clock = clock
        self._links: list = []
        self._errors: list[str] = []
        self._armed = False
        self._seq = 0
        n = len(uris)
        self._heard = np.full(n, -np.inf)
        self._applied = np.zeros(4 * n)
        self._battery = np.zeros(n)
        self._gyro = np.zeros((n, 3))
        self._stopped = np.zeros(n, bool)
        self._stop_sent = False

    # -- Backend protocol ---------------------------------------------------------------------------------------
    def connect(self) -> None:
        if self._links:
            return
        try:
            for uri in self.uris:
                self._links.append(_link_driver(uri, lambda msg, uri=uri: self._errors.append(f"{uri}: {msg}")))
        except CrazyflieLinkError:
            self.close()
            raise
        self._send_all(np.zeros(4 * len(self.uris)), armed=False)

    def preflight(self) -> PreflightReport:
        if not self._links:
            return PreflightReport(False, ("not connected",))
        deadline = self._clock() + self.settings.preflight_timeout
        since = self._clock()
        while self._clock() < deadline and not np.all(self._heard >= since):
            self._send_all(np.zeros(4 * len(self.uris)), armed=False)
            time.sleep(0.01)
            self._drain()
        issues = [f"module {i} ({uri}) does not answer" for i, uri in enumerate(self.uris) if self._heard[i] < since]
        issues += [f"module {i} battery {v:.2f} V < {self.settings.min_battery_v:g} V"
                   for i, v in enumerate(self._battery) if self._heard[i] >= since and v < self.settings.min_battery_v]
        issues += [f"module {i} is emergency-stopped (restart it)" for i in np.flatnonzero(self._stopped)]
        return PreflightReport(not issues, tuple(issues))

    def arm(self) -> None:
        self._armed = True

    def send(self, u: np.ndarray) -> None:
        """Command rotor inputs (4n,), rad^2/s^2; bounded to [0, u_max]; modules ignore them unless armed."""
        self._send_all(applied_command(u, self._applied.size, self._armed, self.u_max), armed=self._armed)

    def telemetry(self) -> Telemetry:
        self._drain()
        fresh = self._heard >= self._clock() - self.settings.link_timeout
        gyro = body_rate(self._rotations, self._gyro)
        return Telemetry(stamp=float(np.max(self._heard)) if np.isfinite(self._heard).any() else 0.0,
                         link_ok=bool(self._links) and bool(np.all(fresh)), motors=self._applied.copy(),
                         battery_v=self._battery.copy(), gyro=gyro)

    def emergency_stop(self) -> None:
        """Supervisor emergency stop and a disarmed zero command to every module, at once."""
        self._armed = False
        for link in self._links:
            link.send_packet(CRTPPacket(wire.STOP_HEADER, bytes([wire.CMD_EMERGENCY_STOP])))
        self._send_all(np.zeros_like(self._applied), armed=False)
        self._applied[:] = 0.0
        self._stop_sent = True

    def close(self) -> None:
        for link in self._links:
            link.close()
        self._links = []

    def __enter__(self) -> CrazyflieBackend:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        if self._links:
            self.emergency_stop()
        self.close()

    # -- wire ---------------------------------------------------------------------------------------------------
    @property
    def link_errors(self) -> list[str]:
        """Errors cflib's link drivers reported, oldest first."""
        return list(self._errors)

    def _send_all(self, u: np.ndarray, armed: bool) -> None:
        self._seq = (self._seq + 1) & 0xFF
        for i, link in enumerate(self._links):
            cmd = wire.MotorCommand(self._seq, armed, tuple(wire.to_counts(u[4 * i:4 * i + 4], self.u_max)))
            link.send_packet(CRTPPacket(wire.APP_HEADER, cmd.pack()))

    def _drain(self) -> None:
        now = self._clock()
        for i, link in enumerate(self._links):
            while (pk := link.receive_packet(0)) is not None:
                if pk.header != wire.APP_HEADER:
                    continue  # console, null packets: not ours
                try:
                    st = wire.ModuleState.unpack(bytes(pk.data))
                except ValueError:
                    continue
                self._heard[i] = now
                # A state sent before the module saw the stop still shows thrust; the stop latches, so only
                # states that report it say what is applied now.
                if st.stopped or not self._stop_sent:
                    self._applied[4 * i:4 * i + 4] = wire.from_counts(st.counts, self.u_max)
                self._battery[i] = st.battery_v
                self._gyro[i] = st.gyro
                self._stopped[i] = st.stopped
