"""The Crazyflie backend through its UDP links (cflib's wire, :mod:`test_udp_link`), against simulated modules
that follow the firmware (supervisor arming, emergency-stop lock, the motor app's state stream and gate)."""

import contextlib
import threading
import time

import numpy as np
import pytest
from cflib.crtp.crtpstack import CRTPPacket

from groundstation.backends import crtp_wire as wire
from groundstation.backends.crazyflie import CrazyflieBackend, CrazyflieSettings
from groundstation.errors import ArmingError, LinkError
from sim.crazyflie_peer import SimulatedCrazyflies
from tests import peers
from tests.peers import ASM, U_MAX, UNTIMED_LINK, hold, stop_peer


def start_peer(port: int, mocap_port: int, **kw):
    return peers.start_peer(SimulatedCrazyflies, port, mocap_port, **kw)


def uris(port: int) -> list[str]:
    return [f"udp://127.0.0.1:{port + i}" for i in range(ASM.n)]


def backend(port: int, **settings) -> CrazyflieBackend:
    return CrazyflieBackend(uris(port), ASM.params, ASM.module_rotations,
                            CrazyflieSettings(**(UNTIMED_LINK | settings)))


def test_wire_headers_match_cflib():
    pk = CRTPPacket()
    for (port, channel), head in {(13, 2): wire.APP_HEADER, (13, 1): wire.VERSION_HEADER,
                                  (9, 1): wire.SUPERVISOR_HEADER, (6, 1): wire.LEGACY_STOP_HEADER}.items():
        pk.set_header(port, channel)
        assert pk.header == head and wire.port_channel(head) == (port, channel)
    assert wire.same_port(wire.APP_HEADER & ~0x0C, wire.APP_HEADER)  # safelink bits do not matter


def test_commands_reach_the_modules_and_the_state_comes_back():
    peer, th = start_peer(19860, 7471)
    try:
        with backend(19860) as be:
            motor_map = ASM.params.motor_command
            idle_u = float(motor_map.thrust([[motor_map.idle]], [4.0])[0, 0]) / ASM.params.c_f
            assert 0.01 * U_MAX < idle_u < 0.02 * U_MAX  # a Bolt's 7000 / 65535 at 4 V
            peers.check_commands_and_state(be, peer, idle_u)
            assert be.preflight().issues == (
                "module 0 (udp://127.0.0.1:19860) is locked by an emergency stop or watchdog: reboot it",
                "module 1 (udp://127.0.0.1:19861) is locked by an emergency stop or watchdog: reboot it")
    finally:
        stop_peer(peer, th)


def test_supervisor_arming_and_a_normal_end_that_does_not_latch():
    peer, th = start_peer(19840, 7478, platform="bolt")
    try:
        with backend(19840) as be:
            assert be.preflight().ok
            assert not any(peer.firmware(i).supervisor.armed for i in range(ASM.n))  # a Bolt waits to be armed
            hold(be, np.full(8, 0.5 * U_MAX), 0.2)
            assert be.telemetry().motors.max() == 0.0
            be.arm()
            assert all(peer.firmware(i).supervisor.armed for i in range(ASM.n))
            hold(be, np.full(8, 0.5 * U_MAX), 0.3)
            np.testing.assert_allclose(be.telemetry().motors, 0.5 * U_MAX, rtol=1e-3)
            assert all(s.supervisor_armed and s.armed and s.fresh for s in be.module_states())
            be.disarm()
        # Closing confirmed the disarm: supervisors disarmed, nothing locked, the modules can arm again.
        assert not any(peer.firmware(i).supervisor.armed or peer.locked(i) for i in range(ASM.n))
        with backend(19840) as be:
            assert be.preflight().ok
            be.arm()
            hold(be, np.full(8, 0.25 * U_MAX), 0.3)
            np.testing.assert_allclose(be.telemetry().motors, 0.25 * U_MAX, rtol=1e-3)
            be.emergency_stop()
        # The stop is sent, not confirmed (a module that locked answers no more): the modules lock on their next step.
        deadline = time.monotonic() + 2.0
        while not all(peer.locked(i) for i in range(ASM.n)) and time.monotonic() < deadline:
            time.sleep(0.005)
        assert all(peer.locked(i) for i in range(ASM.n))
        with backend(19840) as be, pytest.raises(ArmingError, match=r"module 0 \(udp://127.0.0.1:19840\): its "
                                                                     r"supervisor is locked"):
            be.arm()  # a locked module cannot arm until rebooted
    finally:
        stop_peer(peer, th)


def test_a_module_that_stops_flying_is_a_named_module_fault():
    peer, th = start_peer(19964, 7483)
    try:
        with backend(19964) as be:
            assert be.preflight().ok
            be.arm()
            hold(be, np.full(8, 0.3 * U_MAX), 0.2)
            assert be.telemetry().module_faults == ("", "")
            peer.firmware(1).supervisor.request_arming(False)  # its supervisor disarms (a spin-up timeout, ...)
            hold(be, np.full(8, 0.3 * U_MAX), 0.2)
            faults = be.telemetry().module_faults
            assert faults[0] == "" and faults[1].startswith("disarmed by its supervisor")
            be.disarm()
        with backend(19964) as be:
            assert be.preflight().ok
            be.arm()
            hold(be, np.full(8, 0.3 * U_MAX), 0.2)
            peer.firmware(0).handle(bytes([wire.NULL_HEADER, 0xFE, 0xF0, 0x01]), time.monotonic())  # it reboots
            hold(be, np.full(8, 0.3 * U_MAX), 0.2)
            assert be.telemetry().module_faults[0] == "rebooted (its command counts started again)"
            be.emergency_stop()
    finally:
        stop_peer(peer, th)


def test_the_legacy_stop_alone_locks_a_module():
    """Firmware before 2026.04 drops the supervisor port: the backend's stop also goes the legacy way."""
    peer, th = start_peer(19836, 7479)
    try:
        with backend(19836) as be:
            assert be.preflight().ok
            for m in be._modules:
                m.sender.post(CRTPPacket(wire.LEGACY_STOP_HEADER, bytes([wire.LEGACY_EMERGENCY_STOP])), True)
            deadline = time.monotonic() + 1.0
            while not all(peer.locked(i) for i in range(ASM.n)) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert all(peer.locked(i) for i in range(ASM.n))
    finally:
        stop_peer(peer, th)


def test_module_watchdog_and_link_loss():
    peer, th = start_peer(19864, 7472)
    try:
        with backend(19864, link_timeout=0.1) as be:
            assert be.preflight().ok
            be.arm()
            hold(be, np.full(8, 0.5 * U_MAX), 0.3)
            assert be.telemetry().motors.min() > 0.4 * U_MAX
            time.sleep(0.3)  # the ground station goes silent: each module stops its motors by itself
            assert np.all(peer.sim.telemetry().motors < 0.05 * U_MAX)
            peers.check_link_loss(be, peer, th, 0.1)
    finally:
        stop_peer(peer, th)


def test_link_quality_is_measured_from_the_echo():
    peer, th = start_peer(19832, 7477)
    try:
        with backend(19832) as be:
            assert be.preflight().ok
            hold(be, np.zeros(8), 0.6)
            q = be.link_quality()
            # Both measured for every module; nothing lost on loopback.
            assert np.all(np.isfinite(q.latency_s)) and np.all(q.latency_s >= 0)  # measured (values: benchmark)
            assert np.all(q.loss == 0.0)
            tel = be.telemetry()
            np.testing.assert_array_equal(tel.link_loss, q.loss)
    finally:
        stop_peer(peer, th)


def test_preflight_names_silent_weak_and_stock_modules():
    with backend(19868, preflight_timeout=0.3) as be:
        assert be.preflight().issues == ("module 0 (udp://127.0.0.1:19868) does not answer",
                                         "module 1 (udp://127.0.0.1:19869) does not answer")
    peer, th = start_peer(19870, 7473, battery_v=3.3)
    try:
        with backend(19870) as be:
            issues = be.preflight().issues
            assert issues[0] == "module 0 battery 3.30 V < 3.5 V"
            # The Bolt map reaches c_f u_max only from 3.5 V on: at 3.3 V full command gives (3.3/3.5)^2 of it.
            assert issues[1] == ("module 0 (udp://127.0.0.1:19870) reaches 1.38 N per rotor at 3.30 V; the "
                                 "assembly assumes up to c_f u_max = 1.55 N")
    finally:
        stop_peer(peer, th)
    peer, th = start_peer(19876, 7476, motor_app=False)
    try:
        with backend(19876, preflight_timeout=0.4) as be:
            assert be.preflight().issues == tuple(
                f"module {i} (udp://127.0.0.1:{19876 + i}) runs no motor app of contract 3 (it does not answer the "
                f"claim): flash firmware/crazyflie_app (motorApp.version 3)" for i in range(2))
    finally:
        stop_peer(peer, th)


def test_unopenable_link():
    with pytest.raises(LinkError, match="cannot open radio://0/80/2M/E7E7E7E701"):
        CrazyflieBackend(["radio://0/80/2M/E7E7E7E701"], ASM.params, ASM.module_rotations[:1]).connect()
    with pytest.raises(ValueError, match="2 links for 1 modules"):
        CrazyflieBackend(["udp://127.0.0.1:1", "udp://127.0.0.1:2"], ASM.params, ASM.module_rotations[:1])


@contextlib.contextmanager
def _relayed_peer(peer_port: int, relay_port: int, mocap_port: int, **faults):
    """Simulated modules at ``peer_port`` behind an in-process ``sim.udp_relay`` at ``relay_port``."""
    from sim.udp_relay import Faults, UdpRelay

    peer, th = start_peer(peer_port, mocap_port)
    relay = UdpRelay(relay_port, peer_port, 2, Faults(**faults))
    relay_th = threading.Thread(target=relay.run, daemon=True)
    relay_th.start()
    try:
        yield peer
    finally:
        relay.stop()
        relay_th.join(2)
        stop_peer(peer, th)


def _applied(peer) -> list[np.ndarray]:
    return [wire.from_counts(peer.firmware(i).app.latest.counts) for i in range(2)]


def test_commands_ways_swapped_back_and_forth_every_60_ms_are_followed():
    """A relay swapping the commands' ways back and again every 60 ms for 1.5 s: every swap is a trade that brings
    the commands back, so the trades go on as long as the swaps do (eight a flight ran out in 0.5 s and stopped the
    motors 0.4-0.7 m up: hostile campaign 34); each module flies its own commands again after, no module fault."""
    with _relayed_peer(19980, 19984, 7495, swap_after_s=2.0, swap_way="commands", swap_every_s=0.06) as peer, \
            backend(19984) as be:
        assert be.preflight().ok
        be.arm()
        u = np.array([0.2] * 4 + [0.4] * 4) * U_MAX
        hold(be, u, 3.0)  # the swaps start 2 s after the relay's first packet (~1 s ago): 1.5 s and more of them
        assert be.telemetry().module_faults == ("", ""), be.telemetry().module_faults
        assert "commands' ways traded places" in be.telemetry().rerouted
        own = 0
        for _ in range(20):  # each module applies its own command (0.2 or 0.4 of u_max) most of the time
            hold(be, u, 0.02)
            now = _applied(peer)
            own += now[0].mean() < now[1].mean()
        assert own >= 5 and be.telemetry().link_ok, own  # 12 or more of 20 idle (2 runs); each swap starves ~5 states
        be.disarm()


@pytest.mark.parametrize("way, port, counts_apart", [("both", 19760, 0), ("answers", 19766, 0),
                                                     ("commands", 19778, 0), ("both", 19790, 20000)])
def test_links_swapped_in_flight_are_found_by_the_modules_ids_and_re_routed(way, port, counts_apart):
    """Fresh modules all give token 1: preflight claims again until each module's token is its own, so a command
    down the wrong link is dropped. A relay swaps the two links in flight: the claims' answers name the other
    modules, the ways in trade places (each module's states its own); where the commands' way was swapped too
    (both ways), the modules then drop every command and the commands' ways trade places as well; where only the
    answers' was, they stay; where only the commands' was, the answers say nothing and the two modules dropping every
    command trade theirs. Each module flies its own commands again; said in the telemetry (the flight lands).
    ``counts_apart``: module 1 has answered that many more batches since boot than module 0, as real modules' loss
    histories make them (the other module's states on a swapped way, judged against its own counts, read as a
    reboot: a module fault, on the V a stop; simulated modules started together hid it)."""
    with _relayed_peer(port, port + 4, port - 12258, swap_after_s=3.0, swap_way=way) as peer, \
            backend(port + 4) as be:
        peer.firmware(1).app.received = counts_apart
        assert be.preflight().ok
        tokens = [peer.firmware(i).app.owner_token for i in range(2)]
        assert tokens[0] != tokens[1] and all(tokens), tokens
        be.arm()
        u = np.array([0.2] * 4 + [0.4] * 4) * U_MAX  # each module's own command
        hold(be, u, 0.2)
        assert be.telemetry().rerouted == ""
        applied = _applied(peer)
        deadline = time.monotonic() + 6.0  # the swap comes 3 s after the first packet
        said = {"links 0 and 1 re-routed": way != "commands", "commands' ways traded places": way != "answers"}
        while not all(s in be.telemetry().rerouted for s, due in said.items() if due) and time.monotonic() < deadline:
            hold(be, u, 0.05)
        rerouted = be.telemetry().rerouted
        assert {s: s in rerouted for s in said} == said, rerouted
        hold(be, u, 0.3)
        assert be.telemetry().rerouted == rerouted  # settled: no more trading
        now = _applied(peer)
        assert np.allclose(now, applied) and not np.allclose(now[0], now[1])  # each its own again
        assert be.telemetry().link_ok and be.telemetry().module_faults == ("", "")
        be.disarm()


def test_a_module_whose_claims_go_unanswered_in_flight_is_named():
    """A relay that holds back one module's claim answers (to hide a swap that follows): 0.25 s later the flight
    is told its link can no longer be checked, naming the module (it lands on it). Meanwhile it is claimed every
    12 ms, not every 50: the silence is many claims, which a lossy link's chance alone does not silence."""
    with _relayed_peer(19772, 19776, 7516) as peer, backend(19776) as be:
        assert be.preflight().ok
        be.arm()
        u = np.full(8, 0.3 * U_MAX)
        hold(be, u, 0.2)
        firmware = peer.firmware(1)
        answer = firmware._app_packet
        claims = []
        firmware._app_packet = lambda body, now: (claims.append(now) or []) if wire.Claim.unpack(body) else \
            answer(body, now)
        hold(be, u, 0.15)
        assert be.telemetry().rerouted == ""  # not yet
        hold(be, u, 0.1)
        chased = np.diff([t for t in claims if t > claims[0] + 0.08])  # answers overdue from ~62 ms on
        assert chased.size >= 3 and np.median(chased) < 0.03, np.diff(claims)
        hold(be, u, 0.2)
        said = be.telemetry().rerouted
        assert said.startswith(f"module 1 (udp://127.0.0.1:19777, {be.module_ids()[1]}) has answered no claim for "
                               ) and said.endswith("ms: its link can no longer be checked"), said
        assert be.telemetry().link_ok  # its states still come: a landing, not a stop
        be.disarm()


def test_one_state_saying_locked_is_not_a_module_fault():
    """One state with the lock bit flipped (a relay's, or a bit error) is not latched: the next state says the
    module flies (before: the V's motors stopped 0.75 m up, hostile campaign 34). A module that did lock says so
    in its next state too: named."""
    peer, th = start_peer(19970, 7494)
    try:
        with backend(19970) as be:
            assert be.preflight().ok
            be.arm()
            u = np.full(8, 0.3 * U_MAX)
            hold(be, u, 0.2)
            firmware = peer.firmware(0)
            flags, flipped = firmware._flags, []

            def once_locked(now):
                if not flipped:
                    flipped.append(now)
                    return flags(now) | wire.STATE_LOCKED
                return flags(now)

            firmware._flags = once_locked
            hold(be, u, 0.2)
            assert flipped and be.telemetry().module_faults == ("", "")
            firmware._flags = lambda now: flags(now) | wire.STATE_LOCKED  # it locked
            hold(be, u, 0.1)
            assert be.telemetry().module_faults[0].startswith("locked by its supervisor")
            be.disarm()
    finally:
        stop_peer(peer, th)
