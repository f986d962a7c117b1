"""Crazyflie modules over CRTP links: one link per module, forces on the app channel.

Each module runs the motor app (``firmware/crazyflie_app``, crazyflie-firmware >= 2026.04);
:mod:`groundstation.backends.crtp_wire` holds the packets. A link is chosen by URI: cflib's radio driver for
``radio://0/80/2M/E7E7E7E701`` (a Crazyradio), our stamped UDP link for ``udp://127.0.0.1:19850`` (a simulated
or software-in-the-loop module, cflib's UDP wire). Links are used directly rather than through
``cflib.crazyflie.Crazyflie``: the control loop needs one small packet per module
per period and nothing of the connection set-up (TOC download, parameters) on its path.

Sending never blocks the control loop. Over UDP a send is one datagram. cflib's radio driver takes one packet at a
time and its ``send_packet`` waits until the radio thread has taken the previous one (each link's transactions go
through the dongle's one shared thread, ~450-500 a second per dongle): radio links therefore send from a thread of
their own, which always sends the newest command (older ones are superseded) after any pending control packet
(arming, emergency stop). :mod:`groundstation.backends.radio_budget` refuses configurations a dongle cannot carry.

Link quality is measured from what the app reports: the round trip from the send time of the command whose
sequence a state echoes (median of the newest few), and the loss from the app's count of accepted commands
against the sequence numbers it saw go by over ``quality_window`` (a reordered or lost command is not accepted).
Both are per module and reach the flight in :class:`~groundstation.backends.base.Telemetry`, whose failsafe
policy acts on them. The module answers each batch of commands with one state echoing its newest command, and the
loop polls once a period. The round trip ends when the state reached this machine, not when the loop found it:
a busy ground station's lateness is not the link's (it shows as late control periods). Over UDP the link is our
own (:mod:`groundstation.backends.udp_link`), read at the poll with the kernel's arrival stamp of each datagram.
cflib's radio driver queues packets on its own thread and says nothing of their arrival: there a state found by a
poll arrived after the poll before it, and the round trip is taken to that earlier poll (a lower bound).

One flight owns a module set. Connecting takes a host lock per link (:mod:`groundstation.backends.link_lock`);
preflight claims every module for this backend's random session id before anything else (motor app contract
3): a module that flies for another ground station refuses, and its commands carry the token the module gave, so
a module drops any other sender's. The claim's answer names the module (its MCU's unique id: two links to one
module are refused) and the direction of gravity it measures (:meth:`module_gravity`, for the flight's placement
check).

Safety at this edge: commands are bounded (``applied_command``) and carry the armed flag, so a module ignores them
until armed; :meth:`arm` asks each module's supervisor to arm (Bolt and 2.1 Brushless builds require it) and
waits until each can fly, else raises :class:`~groundstation.errors.ArmingError`; :meth:`disarm` ends a flight
normally (zero forces, supervisor disarmed: the module can fly again without a reboot); :meth:`emergency_stop`
sends the supervisor's stop and the legacy one (firmware before 2026.04 drops the first), which lock the module
until it is rebooted. A module that stops flying while armed (disarmed, locked, crashed, restarted, taking another
sender's commands) or whose state stopped for ``link_timeout`` is named in ``Telemetry.module_faults``; a silent
module also makes ``link_ok`` False unless it was isolated (:meth:`isolate`); the app stops its motors by itself
100 ms after the last command.
"""

from __future__ import annotations

import math
import secrets
import statistics
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from cflib.crtp.crtpstack import CRTPPacket

from groundstation.assembly.module import ModuleParams
from groundstation.assembly.motor_map import REQUIRES_ARMING
from groundstation.backends import crtp_wire as wire
from groundstation.backends.base import (
    LOSS_CONFIDENCE_Z,
    BackendBase,
    PreflightReport,
    Telemetry,
    applied_command,
    body_rates,
    wilson_lower,
)
from groundstation.backends.link_lock import LinkLocks
from groundstation.backends.udp_link import StampedUdpLink
from groundstation.errors import ArmingError, LinkError

ARM_RETRY_S = 0.05
"""Interval between repeats of an unanswered supervisor request, s."""
FLYING_HYSTERESIS_S = 2.1
"""The firmware's supervisor counts a module as flying until 2 s after a motor was last over idle (+ margin), s."""
DISARM_CONFIRM_S = 2.5
"""How long closing the backend waits for the modules to confirm a normal disarm and leave their Flying state, s."""
STOP_REPEATS = 3
"""Emergency stops sent per module (each one latches; repeats cover a lost packet)."""
MIN_LOSS_SAMPLES = 10
"""Fewest commands in the quality window for a loss figure."""
REORDER_WINDOW = 64
"""A state whose batch count (received + dropped, mod 65536) is up to this far behind the newest is an older one
overtaken on the link; farther, the module restarted its counts."""
CROSSED_ADVANCE = 1000
"""A state that breaks from its way's module's counts is another module's if it goes on from that one's newest by
at most this many batches (4 s of commands at 250 Hz: a swapped link's states come within a claim period)."""
ECHO_WINDOW = 1000
"""A module flying on a command this backend sent is echoing one of its newest sequence numbers (4 s at 250 Hz);
an echo outside them is another sender's command (its sequence numbers ahead of ours, so the module drops ours)."""
CLAIM_SILENCE_S = 0.25
"""In flight, a module whose claim answers stopped this long can no longer be shown to be on its link: the flight
lands (a relay that holds the answers back would otherwise hide a swap that follows), s. Its claims go out every
:data:`CLAIM_CHASE_S` once an answer is overdue, so the silence is some 16 claims unanswered, not four: at the loss
a link may fly with (10 % each way) four in a row went unanswered in a third of 16 s flights, sixteen in under 1e-8."""
CLAIM_CHASE_S = 0.012
"""A module whose claim answer is overdue (none for :data:`IDENTITY_PERIOD_S` and this) is claimed this often until
one comes, s: three periods at 250 Hz, so a slow radio's queue of claims never holds the commands back."""
STARVED_STATES = 5
"""A module whose states report this many batches in a row of only dropped commands gets none of ours with its
token: after a re-route, the commands' way was swapped too (its partner's link carries them)."""
MAX_FUTILE_TRADES = 3
"""Trades of two starving modules' commands' ways in a row that bring neither module's commands back: then the
modules are faulty. Every trade that does bring them back starts the count again, so a relay swapping back and
forth is followed however often it swaps (traded once a flight, a second swap stopped the motors 0.7-0.97 m up:
hostile campaign 33; eight a flight, a swap every 60 ms used them up in 0.5 s and stopped them 0.4-0.7 m up:
campaign 34)."""
IDENTITY_PERIOD_S = 0.05
"""In flight each module is claimed again this often (the same session keeps its token; the answer names the
module): a link that reaches another module than its own is found within a period of this and a round trip, s.
Over the radio it is a packet every 12 commands at 250 Hz."""
PREFLIGHT_EXCHANGE_S = 1.0
"""Preflight streams disarmed zeros this long and judges the loss over all of it (250 commands at 250 Hz: a link
losing 2 % shows over 10 % with probability below 1e-9), s."""


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


def _link_driver(uri: str, on_error, clock):
    """An open link for ``uri``: our own for ``udp://`` (kernel arrival stamps, see :mod:`udp_link`), cflib's
    driver for every other kind (the radio)."""
    import cflib.crtp

    if uri.startswith("udp://"):
        try:
            return StampedUdpLink(uri, on_error, clock)
        except (OSError, ValueError) as exc:
            raise LinkError(f"cannot open {uri}: {exc}") from None
    ensure_drivers()
    try:
        driver = cflib.crtp.get_link_driver(uri, link_error_callback=on_error)
    except Exception as exc:  # driver-specific errors (no dongle, bad address)
        raise LinkError(f"cannot open {uri}: {exc}") from None
    if driver is None:
        raise LinkError(f"cannot open {uri}: no cflib driver accepts this URI")
    return driver


class _ThreadSender:
    """Sends for a link whose send blocks (cflib's radio driver), on a thread of its own: pending control packets
    first, then the newest command; a command not yet sent when a newer one comes is superseded."""

    def __init__(self, driver, name: str) -> None:
        self._driver = driver
        self._cond = threading.Condition()
        self._priority: deque = deque()
        self._latest: CRTPPacket | None = None
        self._closed = False
        self.superseded = 0
        """Commands replaced by a newer one before the radio could take them."""
        self._thread = threading.Thread(target=self._run, name=f"crtp-send-{name}", daemon=True)
        self._thread.start()

    def post(self, pk: CRTPPacket, priority: bool = False) -> None:
        with self._cond:
            if priority:
                self._priority.append(pk)
            else:
                self.superseded += self._latest is not None
                self._latest = pk
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._closed or self._priority or self._latest is not None)
                if self._priority:
                    pk = self._priority.popleft()
                elif self._latest is not None:
                    pk, self._latest = self._latest, None
                else:
                    return  # closed, nothing left
            self._driver.send_packet(pk)

    def close(self, timeout: float = 1.0) -> None:
        with self._cond:
            self._closed = True
            self._latest = None
            self._cond.notify()
        self._thread.join(timeout)


class _DirectSender:
    """Sends on the caller's thread, for drivers whose send does not wait (UDP: one datagram)."""

    superseded = 0

    def __init__(self, driver) -> None:
        self._driver = driver

    def post(self, pk: CRTPPacket, priority: bool = False) -> None:
        self._driver.send_packet(pk)

    def close(self, timeout: float = 1.0) -> None:
        pass


def _receiver(driver):
    """``driver``'s poll: () -> (packet, arrival s, or None when the driver does not know it) | None."""
    if isinstance(driver, StampedUdpLink):
        return driver.receive

    def receive():
        pk = driver.receive_packet(0)
        return None if pk is None else (pk, None)

    return receive


def _sender_for(driver, name: str):
    from cflib.crtp.radiodriver import RadioDriver

    return _ThreadSender(driver, name) if isinstance(driver, RadioDriver) else _DirectSender(driver)


@dataclass(frozen=True)
class CrazyflieSettings:
    link_timeout: float = 0.1
    """A module whose state is older than this is lost, s."""
    min_battery_v: float = 3.5
    """Preflight: lowest acceptable battery voltage, V."""
    preflight_timeout: float = 1.5
    """Preflight: how long to wait for every module's answers, s (at least ``PREFLIGHT_EXCHANGE_S``)."""
    arm_timeout: float = 3.0
    """How long :meth:`CrazyflieBackend.arm` waits for every module to be able to fly, s: a 2.1 Brushless spins
    its motors up through a 200 ms RPM check and gives up after 2 s."""
    command_period: float = 0.004
    """The flight's control period: preflight streams and polls at it, so the round trips it measures are the
    flight's (over the radio they end at a poll), s."""
    quality_window: float = 0.5
    """The loss is taken over the states of this last stretch, s."""
    latency_samples: int = 5
    """The round trip is the median of this many newest echoes (5 states: 50 ms, so a slow link is seen within
    a few attitude-loop time constants)."""
    max_latency: float = 0.014
    """Preflight: largest acceptable command round trip (median over the window), s."""
    max_loss: float = 0.1
    """Preflight: largest acceptable fraction of commands lost or reordered."""


@dataclass(frozen=True, eq=False)
class LinkQuality:
    """Per module, over the last ``quality_window``."""

    latency_s: np.ndarray
    """Median round trip of a command (send to the arrival of the state that echoes it) over the newest echoes,
    s; NaN until measured. Over the radio each is a lower bound: from the send to the last poll that did not find
    the state yet (0 if the state came within the period)."""
    loss: np.ndarray
    """Fraction of commands the module did not accept (lost, reordered, duplicated); NaN until measured."""


class _Module:
    """What the backend knows of one module."""

    def __init__(self, driver, sender) -> None:
        self.driver = driver
        self.sender = sender
        self.receive = _receiver(driver)
        self.heard = -np.inf
        """When the newest state arrived (poll time), s."""
        self.state: wire.ModuleState | None = None
        self.version: int | None = None
        """CRTP protocol version the firmware reported."""
        self.arm_reply: tuple[bool, bool] | None = None
        """(granted, armed) of the newest supervisor answer."""
        self.samples: deque = deque()
        """(time, echoed sequence, accepted count) of recent states, for the loss."""
        self.rtts: deque = deque()
        """Round trips of the newest states that echoed a new sequence, s."""
        self.fault = ""
        """Why the module stopped flying since arming ("" while it flies); latched."""
        self.fault_said = ""
        """What its newest state said of its firmware ("" if nothing): latched as :attr:`fault` when the next says
        it stopped flying too."""
        self.identity: wire.Identity | None = None
        """The newest answer to a claim."""
        self.uid = ""
        """The unique id of the module this link reached at the end of preflight (hex; "" before)."""
        self.seen_uid = ""
        """The unique id in the newest claim answer on this module's way in (hex)."""
        self.answered = -np.inf
        """When the newest claim answer came on this module's way in, s."""
        self.starved = 0
        """States in a row that report only dropped commands (none of ours accepted)."""
        self.traded = False
        """Its commands' way was traded, and it has accepted none of ours since."""
        self.claimed = -np.inf
        """When this module was last claimed in flight, s."""
        self.claims_silent = False
        """Its claims' silence was said (once a flight)."""
        self.partner: int | None = None
        """The module whose way in this one's traded places with (a re-route), until their commands' ways are
        settled too: traded, or this module accepts ours again."""
        self.token = 0
        """The token the module gave this backend's session (0: not claimed)."""
        self.unknown = 0
        """Packets on no port this backend speaks (a link that is not a Crazyflie's sends nothing else)."""


def _age_text(age: float) -> str:
    return "never heard" if not np.isfinite(age) else f"for {age * 1e3:.0f} ms"


def _batches(st: wire.ModuleState) -> int:
    """Batches the module has answered since boot (mod 65536): each accepted or dropped command counts one."""
    return st.received + st.dropped


def _signed16(x: int) -> int:
    """A difference of two wrapping 16-bit counters, in -32768..32767."""
    return ((x + 0x8000) & 0xFFFF) - 0x8000


class CrazyflieBackend(BackendBase):
    """``n`` Crazyflie modules of one assembly, in assembly order (module i drives rotors 4i..4i+3)."""

    def __init__(self, uris: list[str] | tuple[str, ...], module: ModuleParams, module_rotations: np.ndarray,
                 settings: CrazyflieSettings | None = None, clock=time.monotonic) -> None:
        if len(uris) != len(module_rotations):
            raise ValueError(f"{len(uris)} links for {len(module_rotations)} modules")
        if module.motor_command is None:
            raise ValueError("the module parameters have no motor_command: the Crazyflie backend needs the "
                             "platform's thrust map")
        self.uris = tuple(uris)
        self.module = module
        self.u_max = module.u_max
        self.settings = settings or CrazyflieSettings()
        self._map = module.motor_command
        self._rotations = np.asarray(module_rotations, float)
        self._clock = clock
        self._modules: list[_Module] = []
        self._errors: list[str] = []
        self._armed = False
        self._disarm_requested = False
        self._stop_sent = False
        self._isolated: set[int] = set()
        """Modules taken out of the flight (:meth:`isolate`)."""
        self._seq = 0
        self._thrust_sent = -np.inf
        """When a command with thrust was last sent, s."""
        self._sent = 0
        """Commands sent per module by this backend (its sequence numbers are 1..sent, mod 65536)."""
        self._sent_at = np.full(1 << 16, np.nan)
        """Send time of each sequence number, s."""
        n = len(uris)
        self._counts = np.zeros((n, 4))
        """Normalized forces each module reports applied."""
        self._battery = np.zeros(n)
        self._gyro = np.zeros((n, 3))
        self._window = self.settings.quality_window
        """Stretch of states the loss is taken over, s."""
        self._polled = -np.inf
        """When the links were last polled for states, s."""
        self.session = secrets.randbits(32) or 1
        """This backend's session id, claimed on every module (never 0)."""
        self._identity_sent = -np.inf
        """When the modules were last claimed in flight, s."""
        self.rerouted = ""
        """How the links stopped being what preflight checked, in flight ("" if never): re-routed, a module's claims
        unanswered."""
        self._futile_trades = 0
        """Trades of two modules' commands' ways in a row that brought neither's commands back (at most
        :data:`MAX_FUTILE_TRADES`)."""
        self._locks = LinkLocks(self.uris)

    # -- Backend protocol ---------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Take the links' host locks and open them (nothing is sent: commands wait for the preflight's claim)."""
        if self._modules:
            return
        self._locks.acquire()
        try:
            for i, uri in enumerate(self.uris):
                driver = _link_driver(uri, lambda msg, uri=uri: self._errors.append(f"{uri}: {msg}"), self._clock)
                self._modules.append(_Module(driver, _sender_for(driver, f"m{i}")))
        except LinkError:
            self.close()
            raise

    def _claim(self) -> list[str]:
        """Claim every module for this session (repeated until answered, up to ``preflight_timeout``); issues for
        the modules that did not answer, fly for another session, or are reached by two links."""
        since = self._clock()
        deadline = since + self.settings.preflight_timeout
        claim = CRTPPacket(wire.APP_HEADER, wire.Claim(self.session).pack())
        version = CRTPPacket(wire.VERSION_HEADER, bytes([wire.GET_PROTOCOL_VERSION]))
        for m in self._modules:
            m.identity = None
        while self._clock() < deadline:
            for m in self._modules:
                if m.identity is None:
                    m.sender.post(claim, True)
                if m.version is None:  # the firmware answers it without the app: tells "no app" from "silent"
                    m.sender.post(version, True)
            self._send_all(np.zeros((len(self._modules), 4)), armed=False)  # owned modules keep answering
            time.sleep(self.settings.command_period)
            self._drain()
            if all(m.identity is not None for m in self._modules):
                break  # every module answered (a refusal is final: the owner flies it)
        self._distinct_tokens(deadline)
        issues = []
        for i, (uri, m) in enumerate(zip(self.uris, self._modules, strict=True)):
            ident = m.identity
            if ident is None and m.version is None and m.unknown:
                issues.append(f"module {i} ({uri}) answers with {m.unknown} packets that are no Crazyflie's: not a "
                              f"Crazyflie on this link (a MAVLink module?)")
            elif ident is None and m.version is None:
                issues.append(f"module {i} ({uri}) does not answer")
            elif ident is None:
                issues.append(f"module {i} ({uri}) runs no motor app of contract {wire.APP_VERSION} (it does not "
                              f"answer the claim): flash firmware/crazyflie_app (motorApp.version {wire.APP_VERSION})")
            elif ident.session != self.session:
                issues.append(f"module {i} ({uri}) flies for another ground station (session {ident.session:08x}): "
                              f"one flight owns a module set")
        seen: dict[str, int] = {}
        for i, m in enumerate(self._modules):
            if m.identity is None:
                continue
            first = seen.setdefault(m.identity.uid_hex, i)
            if first != i:
                issues.append(f"module {first} ({self.uris[first]}) and module {i} ({self.uris[i]}) are one module "
                              f"(unique id {m.identity.uid_hex}): two links reach it")
        return issues

    def _distinct_tokens(self, deadline: float) -> None:
        """Modules claimed for this session whose tokens coincide are claimed again, by a throwaway session and then
        by this one (each claim by a new owner moves the module's token on), until every module's token is its own:
        a command sent down another module's link then carries a token that module drops. Fresh modules all give
        token 1, and links swapped mid-flight by a relay had each module fly the other's commands (the V flipped;
        hostile campaign 30)."""
        taken: set[int] = set()
        for m in self._modules:
            while (m.identity is not None and m.identity.session == self.session and m.token in taken
                   and self._clock() < deadline):
                for session in (secrets.randbits(32) or 1, self.session):
                    claim = CRTPPacket(wire.APP_HEADER, wire.Claim(session).pack())
                    m.identity = None
                    while (m.identity is None or m.identity.session != session) and self._clock() < deadline:
                        m.sender.post(claim, True)
                        time.sleep(self.settings.command_period)
                        self._drain()
            taken.add(m.token)

    def module_gravity(self) -> np.ndarray | None:
        """Per module, the direction of the specific force its accelerometer measured at the claim (module frame,
        unit; at rest: up), or None if a module has not answered."""
        if not self._modules or any(m.identity is None for m in self._modules):
            return None
        return np.array([m.identity.gravity_up for m in self._modules])

    def module_ids(self) -> list[str | None]:
        """Per module, its MCU's unique id (hex) from the claim's answer."""
        return [m.identity.uid_hex if m.identity is not None else None for m in self._modules]

    def preflight(self) -> PreflightReport:
        """Every module is claimed for this session (one owner; distinct modules), answers with a recent enough
        firmware running the motor app, unlocked, with battery and link quality good enough; streams disarmed zeros
        meanwhile (nothing spins)."""
        if not self._modules:
            return PreflightReport(False, ("not connected",))
        for m in self._modules:
            m.uid = ""  # learnt afresh below
        claimed = self._claim()
        if claimed:
            return PreflightReport(False, tuple(claimed))
        s = self.settings
        since = self._clock()
        deadline = since + s.preflight_timeout
        settled = since + PREFLIGHT_EXCHANGE_S
        for m in self._modules:
            m.samples.clear()
        self._window = np.inf  # the loss over the whole exchange
        while self._clock() < deadline:
            for m in self._modules:
                if m.version is None:
                    m.sender.post(CRTPPacket(wire.VERSION_HEADER, bytes([wire.GET_PROTOCOL_VERSION])), True)
            self._send_all(np.zeros((len(self._modules), 4)), armed=False)
            time.sleep(s.command_period)
            self._drain()
            heard_all = all(m.version is not None and m.heard >= since for m in self._modules)
            if heard_all and self._clock() >= settled:
                break
        quality = self.link_quality()
        self._window = s.quality_window
        # Ask again (the same session keeps its token): the identity's accelerometer reading is then the one at
        # the end of preflight, the assembly at rest where the flight's placement check compares it with mocap.
        issues = self._claim()
        for m in self._modules:  # what each link reaches; in flight it must go on reaching it
            m.uid = m.identity.uid_hex if m.identity is not None else ""
        for i, (uri, m) in enumerate(zip(self.uris, self._modules, strict=True)):
            name = f"module {i} ({uri})"
            if m.version is None and m.heard < since:
                issues.append(f"{name} does not answer")
                continue
            if m.version is not None and m.version < wire.MIN_PROTOCOL_VERSION:
                issues.append(f"{name} runs firmware with CRTP protocol {m.version}; the motor app needs "
                              f">= {wire.MIN_PROTOCOL_VERSION} (crazyflie-firmware 2026.04 or newer)")
            if m.heard < since:
                issues.append(f"{name} sends no motor-app state: flash firmware/crazyflie_app (motorApp.version "
                              f"{wire.APP_VERSION})")
                continue
            if m.state.locked:
                issues.append(f"{name} is locked by an emergency stop or watchdog: reboot it")
            if self._battery[i] < s.min_battery_v:
                issues.append(f"module {i} battery {self._battery[i]:.2f} V < {s.min_battery_v:g} V")
            reach = float(self._map.max_thrust(self._battery[i])[0])
            need = self.module.c_f * self.u_max
            if reach < need * (1 - 1e-6):
                issues.append(f"{name} reaches {reach:.3g} N per rotor at {self._battery[i]:.2f} V; the assembly "
                              f"assumes up to c_f u_max = {need:.3g} N")
            if quality.latency_s[i] > s.max_latency:
                issues.append(f"{name} link round trip {quality.latency_s[i] * 1e3:.0f} ms > "
                              f"{s.max_latency * 1e3:g} ms")
            if quality.loss[i] > s.max_loss:
                issues.append(f"{name} loses {quality.loss[i]:.0%} of commands (> {s.max_loss:.0%})")
        return PreflightReport(not issues, tuple(issues))

    def arm(self) -> None:
        """Ask every module's supervisor to arm and wait, per module, until it reports that it can fly (on a 2.1
        Brushless that means its motors spun up through the RPM check at the idle floor); streams disarmed zeros
        meanwhile, so the modules answer and nothing but the idle floor spins. A refusal is asked again until
        ``arm_timeout`` (a supervisor refuses during its re-arm cycle and just after boot); a locked module is
        final. Raises ArmingError (every module asked to disarm) unless all can fly. Flight must follow at once: a
        supervisor disarms after 30 s armed without flying."""
        if not self._modules:
            raise ArmingError("not connected")
        if not all(m.token for m in self._modules):  # arming needs the modules' ownership: claim (preflight does)
            claimed = self._claim()
            if claimed:
                raise ArmingError("; ".join(claimed))
        try:
            self._arm()
        except BaseException:  # refused, or interrupted half-way (Ctrl-C): no supervisor stays armed
            self._request_disarm()
            raise

    def _arm(self) -> None:
        for m in self._modules:
            m.arm_reply = None
        pending = set(range(len(self._modules)))
        locked: set[int] = set()
        since = self._clock()
        deadline = since + self.settings.arm_timeout
        next_request = since
        while pending and self._clock() < deadline:
            if self._clock() >= next_request:
                for i in pending:
                    m = self._modules[i]
                    reply, st = m.arm_reply, m.state if m.heard >= since else None
                    # Unanswered, refused, or armed and then disarmed again (a 2.1 Brushless's spin-up timeout, a
                    # 2.x's pre-flight timeout): ask again.
                    if reply is None or not reply[1] or (st is not None and not st.supervisor_armed):
                        m.sender.post(CRTPPacket(wire.SUPERVISOR_HEADER, wire.arm_request(True)), True)
                next_request = self._clock() + ARM_RETRY_S
            self._send_all(np.zeros((len(self._modules), 4)), armed=False)
            time.sleep(self.settings.command_period)
            self._drain()
            for i in list(pending):
                m = self._modules[i]
                if m.heard >= since and m.state.locked:
                    locked.add(i)
                    pending.discard(i)
                elif m.heard >= since and m.state.can_fly and m.arm_reply is not None and m.arm_reply[1]:
                    pending.discard(i)
        refused = {i: "its supervisor is locked (emergency stop or watchdog): reboot it" for i in locked}
        for i in pending:
            m = self._modules[i]
            reply = m.arm_reply
            if m.heard < since:
                why = "sends no state"
            elif reply is None:
                why = "no answer to the arming request"
            elif not reply[1]:
                why = "its supervisor refused to arm (tumbled, or not ready)"
            else:
                why = "armed but its supervisor does not let it fly (motors not spinning up through the RPM check?)"
            refused[i] = f"{why} within {self.settings.arm_timeout:g} s"
        if refused:
            raise ArmingError("; ".join(f"module {i} ({self.uris[i]}): {why}" for i, why in sorted(refused.items())))
        self._armed = True
        self._disarm_requested = False
        for m in self._modules:
            m.fault = m.fault_said = ""
            m.answered = self._clock()  # the claim clock starts at arming (preflight's answers checked the links)
            m.claims_silent = False

    def send(self, u: np.ndarray) -> None:
        """Command rotor inputs (4n,), rad^2/s^2; bounded to [0, u_max]; modules ignore them unless armed; isolated
        modules get zero."""
        u = applied_command(u, self._counts.size, self._armed, self.u_max)
        thrust = (self.module.c_f * u).reshape(-1, 4)
        fractions = self._map.fractions(thrust, self._battery)
        if self._isolated:  # only after a module fault: nothing on the normal per-period path
            fractions[sorted(self._isolated)] = 0.0
        self._send_all(fractions, armed=self._armed)
        if not self._armed:
            return
        now = self._clock()
        regular = now - self._identity_sent >= IDENTITY_PERIOD_S
        self._identity_sent = now if regular else self._identity_sent
        claim = CRTPPacket(wire.APP_HEADER, wire.Claim(self.session).pack())
        for m in self._modules:
            overdue = now - m.answered > IDENTITY_PERIOD_S + CLAIM_CHASE_S and now - m.claimed >= CLAIM_CHASE_S
            if regular or overdue:
                m.claimed = now
                m.sender.post(claim, True)  # not in the command's slot: a newer command would supersede it

    def isolate(self, modules) -> bool:
        """Take faulty modules out of the flight: each gets the emergency stop (it locks until rebooted) and zero
        commands, and its link no longer counts for ``link_ok``; the others fly on."""
        for i in modules:
            self._isolated.add(int(i))
            for _ in range(STOP_REPEATS):
                self._modules[i].sender.post(CRTPPacket(wire.SUPERVISOR_HEADER, bytes([wire.CMD_EMERGENCY_STOP])),
                                             True)
                self._modules[i].sender.post(CRTPPacket(wire.LEGACY_STOP_HEADER,
                                                        bytes([wire.LEGACY_EMERGENCY_STOP])), True)
        return True

    def idle_inputs(self) -> np.ndarray:
        """The platform's idle floor (``powerDist.idleThrust``, Bolt and 2.1 Brushless) at each module's battery."""
        idle = np.full(self._counts.shape, self._map.idle)
        return (self._map.thrust(idle, self._battery) / self.module.c_f).reshape(-1)

    def telemetry(self) -> Telemetry:
        self._drain()
        now = self._clock()
        heard = np.array([m.heard for m in self._modules]) if self._modules else np.zeros(0)
        fresh = heard >= now - self.settings.link_timeout
        if not fresh.all():
            # Modules that went quiet within two periods of a lost one stopped with it (a dead dongle, a peer
            # gone): named together, not one now and the other in a period that the stop has already ended.
            fresh &= heard >= now - self.settings.link_timeout + 2 * self.settings.command_period
        counted = [i for i in range(len(self._modules)) if i not in self._isolated]
        thrust = self._map.thrust(self._counts, self._battery)
        quality = self.link_quality()
        rates = body_rates(self._rotations, self._gyro)
        ages = now - heard  # each state packet carries its module's gyro
        if self._isolated:
            ages[sorted(self._isolated)] = np.inf
            # out of the flight: its link no longer lands or stops it, nor cuts the attitude loop's bandwidth
            quality.latency_s[sorted(self._isolated)] = np.nan
            quality.loss[sorted(self._isolated)] = np.nan
        faults = tuple(m.fault or ("" if ok else f"sends no state ({_age_text(now - m.heard)}): link lost or the "
                                                 f"module is off")
                       for m, ok in zip(self._modules, fresh, strict=True))
        if self._armed:
            for i, m in enumerate(self._modules):
                if i not in self._isolated and now - m.answered > CLAIM_SILENCE_S and not m.claims_silent:
                    m.claims_silent = True
                    seen = f" (its link last answered for {m.seen_uid})" if m.seen_uid != m.uid else ""
                    self._note(f"module {i} ({self.uris[i]}, {m.uid}) has answered no claim "
                               f"{_age_text(now - m.answered)}{seen}: its link can no longer be checked")
        return Telemetry(stamp=float(heard.max()) if heard.size and np.isfinite(heard).any() else 0.0,
                         link_ok=bool(counted) and bool(np.all(fresh[counted])),
                         gyro_age_s=float(now - heard[counted].min()) if counted else float("inf"),
                         module_gyro_ages_s=ages,
                         motors=(thrust / self.module.c_f).reshape(-1), battery_v=self._battery.copy(),
                         gyro=rates.mean(axis=0), module_gyros=rates, link_latency_s=quality.latency_s,
                         link_loss=quality.loss, module_faults=faults, rerouted=self.rerouted)

    def disarm(self) -> None:
        """End a flight normally: zero forces, disarmed, each supervisor asked to disarm and, before this returns,
        confirmed (up to ``DISARM_CONFIRM_S``: see :meth:`_confirm_disarm`). Unlike :meth:`emergency_stop`, the
        modules can fly again without a reboot."""
        self._armed = False
        self._send_all(np.zeros_like(self._counts), armed=False)
        self._request_disarm()
        self._confirm_disarm()
        self._disarm_requested = False

    def emergency_stop(self) -> None:
        """Supervisor emergency stop (and the legacy one) and a disarmed zero command to every module, at once."""
        self._armed = False
        for m in self._modules:
            for _ in range(STOP_REPEATS):
                m.sender.post(CRTPPacket(wire.SUPERVISOR_HEADER, bytes([wire.CMD_EMERGENCY_STOP])), True)
                m.sender.post(CRTPPacket(wire.LEGACY_STOP_HEADER, bytes([wire.LEGACY_EMERGENCY_STOP])), True)
        self._send_all(np.zeros_like(self._counts), armed=False)
        self._counts[:] = 0.0
        self._stop_sent = True

    def close(self) -> None:
        if self._disarm_requested and not self._stop_sent:
            self._confirm_disarm()
        for m in self._modules:
            m.sender.close()
            m.driver.close()
        self._modules = []
        self._locks.release()


    # -- measurements -------------------------------------------------------------------------------------------
    @property
    def link_errors(self) -> list[str]:
        """Errors the links reported, oldest first."""
        return list(self._errors)

    @property
    def superseded(self) -> int:
        """Commands a slow link replaced by a newer one before sending them (radio links)."""
        return sum(m.sender.superseded for m in self._modules)

    def module_states(self) -> list[wire.ModuleState | None]:
        """The newest state of each module (None before the first)."""
        return [m.state for m in self._modules]

    def link_quality(self) -> LinkQuality:
        # Asked every period (telemetry): in Python floats, np.median of a few echoes cost ~50 us per module.
        latency, loss = [math.nan] * len(self._modules), [math.nan] * len(self._modules)
        for i, m in enumerate(self._modules):
            if m.rtts:
                latency[i] = statistics.median(m.rtts)
            if len(m.samples) >= 2:
                (_, seq0, rcv0), (_, seq1, rcv1) = m.samples[0], m.samples[-1]
                sent = (seq1 - seq0) & 0xFFFF
                if sent >= MIN_LOSS_SAMPLES:  # the low end of its interval, as PX4's: a 5 % link read 10 % and
                    lost = min(max(sent - ((rcv1 - rcv0) & 0xFFFF), 0), sent)  # landed (hostile campaign 33)
                    loss[i] = wilson_lower(lost, sent, LOSS_CONFIDENCE_Z)
        return LinkQuality(np.array(latency), np.array(loss))

    # -- wire ---------------------------------------------------------------------------------------------------
    def _send_all(self, fractions: np.ndarray, armed: bool) -> None:
        if armed and np.any(fractions > 0):
            self._thrust_sent = self._clock()
        self._seq = (self._seq + 1) & 0xFFFF
        self._sent += 1
        self._sent_at[self._seq] = self._clock()
        for m, f in zip(self._modules, fractions, strict=False):
            if m.token:  # before the claim the module would drop it (and another owner's module must not see it)
                cmd = wire.MotorCommand(self._seq, armed, wire.to_counts(f), m.token)
                m.sender.post(CRTPPacket(wire.APP_HEADER, cmd.pack()))

    def _module_fault(self, st: wire.ModuleState, restarted: bool) -> str:
        """Why an armed module's firmware no longer flies it ("" if it does)."""
        if restarted:
            return "rebooted (its command counts started again)"
        if (self._seq - st.sequence) & 0xFFFF > ECHO_WINDOW:
            return (f"takes commands from another sender (it applies sequence {st.sequence}, which this ground "
                    f"station did not send)")
        if st.locked:
            return "locked by its supervisor (emergency stop or commander watchdog)"
        if not st.supervisor_armed:
            return "disarmed by its supervisor (tumbled, crashed, spin-up or pre-flight timeout)"
        if not st.can_fly:
            return "its supervisor no longer lets it fly (tumbled or crashed)"
        return ""

    def _request_disarm(self) -> None:
        self._disarm_requested = True
        for m in self._modules:
            m.arm_reply = None
            m.sender.post(CRTPPacket(wire.SUPERVISOR_HEADER, wire.arm_request(False)), True)

    def _confirm_disarm(self) -> None:
        """Stream disarmed zeros until every module has confirmed the disarm and, on auto-arming platforms, its
        flying hysteresis has run out, for at most ``DISARM_CONFIRM_S``; the disarm is repeated to the modules that
        have not confirmed. The zeros matter on an auto-arming 2.x: it arms itself again at once and, a motor having
        been over idle within ``FLYING_HYSTERESIS_S``, is flying again; left without commands it would level out
        after 0.5 s and lock 2 s later (seen on the real firmware)."""
        now = self._clock()
        deadline = now + DISARM_CONFIRM_S
        settled = self._thrust_sent + FLYING_HYSTERESIS_S if not REQUIRES_ARMING[self._map.platform] else now
        repeat = now + ARM_RETRY_S
        confirmed = [False] * len(self._modules)
        while self._clock() < deadline:
            self._send_all(np.zeros_like(self._counts), armed=False)
            time.sleep(self.settings.command_period)
            self._drain()
            for i, m in enumerate(self._modules):
                confirmed[i] = confirmed[i] or (m.arm_reply is not None and not m.arm_reply[1])
            landed = all(m.state is not None and not m.state.flying for m in self._modules)
            if all(confirmed) and landed and self._clock() >= settled:
                return
            if self._clock() >= repeat:
                for i, m in enumerate(self._modules):
                    if not confirmed[i]:
                        m.arm_reply = None
                        m.sender.post(CRTPPacket(wire.SUPERVISOR_HEADER, wire.arm_request(False)), True)
                repeat += ARM_RETRY_S

    def _drain(self) -> None:
        now = self._clock()
        before, self._polled = self._polled, now  # the states found now arrived after ``before``
        window = self._window
        for i, m in enumerate(self._modules):
            while (got := m.receive()) is not None:
                pk, arrival = got
                data = bytes(pk.data)
                if wire.same_port(pk.header, wire.APP_HEADER):
                    if data[:1] == bytes([wire.KIND_IDENTITY]):
                        self._on_identity(i, m, data, now)
                        continue
                    try:
                        st = wire.ModuleState.unpack(data)
                    except ValueError:
                        continue
                    k = self._whose_state(i, st)
                    self._on_state(k, self._modules[k], st, now, before if arrival is None else arrival)
                elif wire.same_port(pk.header, wire.SUPERVISOR_HEADER):
                    m.arm_reply = wire.arm_response(data) or m.arm_reply
                elif wire.same_port(pk.header, wire.VERSION_HEADER):
                    m.version = wire.version_reply(data) or m.version
                elif pk.header != wire.NULL_HEADER:
                    m.unknown += 1
            while m.samples and m.samples[0][0] < now - window:
                m.samples.popleft()

    def _on_identity(self, i: int, m: _Module, data: bytes, now: float) -> None:
        try:
            identity = wire.Identity.unpack(data)
        except ValueError:
            return
        m.seen_uid = identity.uid_hex
        if m.uid and identity.uid_hex != m.uid:  # in flight, module i's way in brings another module's answers
            self._reroute(i, identity.uid_hex)
            return
        m.answered = now
        m.identity = identity
        if identity.session == self.session:
            m.token = identity.token

    def _reroute(self, i: int, uid: str) -> None:
        """Module i's way in brought module j's answer: once j's brings i's (a relay swapped them; a link that
        reaches a module already reached by its own is no swap, and the silence of the other's claims lands the
        flight), the two ways in trade places, so each module's states are its own. Whether the commands' ways
        were swapped too shows next: the states then report only dropped commands (each module drops the other's
        token), and :meth:`_starved` trades the commands' ways as well. Said in :attr:`rerouted`, which lands the
        flight."""
        j = next((k for k, other in enumerate(self._modules) if other.uid == uid), None)
        if j is None or j == i or self._modules[j].seen_uid != self._modules[i].uid:
            return
        a, b = self._modules[i], self._modules[j]
        a.receive, b.receive = b.receive, a.receive
        a.seen_uid, b.seen_uid = a.uid, b.uid
        a.answered = b.answered = self._clock()
        a.starved = b.starved = 0
        a.partner, b.partner = j, i
        self._note(f"module {i}'s link ({self.uris[i]}) brought module {j}'s answers ({uid}): links "
                   f"{min(i, j)} and {max(i, j)} re-routed")

    def _starved(self, i: int, m: _Module) -> None:
        """Module i drops every command of ours (:data:`STARVED_STATES` states): its commands reach another module.
        After a re-route, they go down its partner's link; else, when exactly one other module starves too (a relay
        swapped only the commands' ways, or swapped them back), down that one's (:data:`MAX_FUTILE_TRADES`).
        Otherwise the module is faulty."""
        # Starving too: more than one batch (a duplicated or overtaken one drops alone on a healthy module).
        others = [k for k, o in enumerate(self._modules) if k != i and o.starved > STARVED_STATES // 2]
        j = m.partner if m.partner is not None else others[0] if len(others) == 1 else None
        j = j if self._futile_trades < MAX_FUTILE_TRADES else None
        if j is None and not others and m.starved < 2 * STARVED_STATES:
            return  # the other may not have reported its first drop yet
        if j is None:
            m.fault = m.fault or (f"drops every command of ours ({m.starved} batches in a row): they reach it without "
                                  f"its token")
            return
        a, b = m, self._modules[j]
        a.sender, b.sender = b.sender, a.sender
        a.partner = b.partner = None
        a.starved = b.starved = 0
        a.traded = b.traded = True
        self._futile_trades += 1
        self._note(f"modules {min(i, j)} and {max(i, j)} dropped every command: their commands' ways traded places "
                   f"too")

    def _note(self, note: str) -> None:
        if note not in self.rerouted:
            self.rerouted = f"{self.rerouted}; {note}" if self.rerouted else note

    def _whose_state(self, i: int, st: wire.ModuleState) -> int:
        """The module a state on module i's way in came from: i's, unless its counts break from i's newest
        (farther behind than a reordering, or ahead by more than :data:`CROSSED_ADVANCE`) but go on from exactly
        one other module's newest, by at most that (a relay that swapped the links: until the claims re-route the
        ways in, the other's states come on this way, and judged against this module's counts, which differ by the
        modules' loss histories since boot, read as a reboot: a module fault, on the V a stop)."""
        own = self._modules[i].state
        if own is None or -REORDER_WINDOW < _signed16(_batches(st) - _batches(own)) <= CROSSED_ADVANCE:
            return i
        others = [k for k, o in enumerate(self._modules) if k != i and o.state is not None and
                  0 < _signed16(_batches(st) - _batches(o.state)) <= CROSSED_ADVANCE]
        return others[0] if len(others) == 1 else i

    def _on_state(self, i: int, m: _Module, st: wire.ModuleState, now: float, arrived: float) -> None:
        """``arrived``: when the state reached this machine (the kernel's stamp), or on a driver that does not say,
        the poll before this one (a lower bound)."""
        previous = m.state
        restarted = False
        if previous is not None:
            # Every state answers a batch of at least one packet, accepted or dropped: received + dropped rises with
            # each. A state that does not advance it was overtaken on a reordering or duplicating link; one that
            # falls far was sent by a module that restarted its counts.
            advance = _signed16(_batches(st) - _batches(previous))
            if -REORDER_WINDOW < advance <= 0:
                return  # an older or repeated state: the newer one stands
            restarted = advance <= -REORDER_WINDOW
        m.state, m.heard = st, now
        if self._armed and previous is not None and not restarted:
            accepted = _signed16(st.received - previous.received)
            m.starved = 0 if accepted > 0 else m.starved + (_signed16(st.dropped - previous.dropped) > 0)
            if accepted > 0:
                m.partner = None  # its commands reach it: a re-route's ways in alone were swapped
                if m.traded:  # a trade that brought its commands back: not futile
                    m.traded, self._futile_trades = False, 0
            if m.starved >= STARVED_STATES:
                self._starved(i, m)
        if self._armed and not m.fault:
            # Latched when two states in a row say the firmware stopped flying it (named by the first: a reboot's
            # next state says "disarmed"): one state with the lock bit flipped (a relay's, or a bit error the
            # radio's CRC missed) stopped the V's motors 0.75 m up; a module that did stop says so again in its next
            # state, 4 ms later.
            said = self._module_fault(st, restarted)
            m.fault, m.fault_said = (m.fault_said if said and m.fault_said else ""), said
        # Only echoes of this backend's own commands measure the link (a module still echoes the previous
        # session's last command until it accepts one of ours).
        ours = self._sent >= 1 << 16 or (st.sequence - 1) & 0xFFFF < self._sent
        if ours and (previous is None or st.sequence != previous.sequence):
            sent = self._sent_at[st.sequence]
            if np.isfinite(sent) and 0.0 <= now - sent < 1.0:
                m.rtts.append(max(arrived - sent, 0.0))
                if len(m.rtts) > self.settings.latency_samples:
                    m.rtts.popleft()
        if ours:
            m.samples.append((now, st.sequence, st.received))
        # A state sent before the module saw the stop still shows thrust; the stop latches, so only states that
        # report the lock say what is applied now.
        if st.locked or not self._stop_sent:
            self._counts[i] = wire.from_counts(st.counts)
        self._battery[i] = st.battery_v
        self._gyro[i] = st.gyro
