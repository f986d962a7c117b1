"""``groundstation fly`` and ``groundstation log recover``."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
from dataclasses import asdict

import click
from rich.console import Console
from rich.live import Live
from rich.table import Table

from groundstation.backend_kinds import KINDS, load
from groundstation.choices import MOCAP_SYSTEMS
from groundstation.cli.common import (
    FINITE,
    STATUS_S,
    FiniteFloat,
    json_safe,
    sim_physics_hz,
    status_text,
    stderr_console,
    writable_output,
)
from groundstation.cli.mocap_cmd import BODY, BodyList, KeyChunks, ListenEndpoint, MockBodies
from groundstation.control.phase import Phase
from groundstation.errors import UsageError
from groundstation.loop_activity import LoopActivity
from groundstation.output import stdout_lost
from groundstation.runtime.signals import LANDING_SIGNALS
from groundstation.runtime.terminal import forget_lost_terminal

EXIT_EMERGENCY = 1
"""A failsafe landing, an emergency stop, a flight that did not start (refused arming, the operator before
arming), or a log writer that failed or hung."""
EXIT_DEGRADED = 3
"""The flight landed as planned (or as the operator asked) but degraded beyond its bounds
(:class:`~groundstation.runtime.flight.QualityBounds`: attitude error, rotor saturation, late periods); the summary
names what. Bad input is 2 (:mod:`groundstation.cli`)."""
KEYS_HINT = "   l/Ctrl-C: land, k/Ctrl-C x2: stop motors"


@click.command("fly")
@click.argument("flight", type=click.Path(dir_okay=False))
@click.option("--duration", type=FINITE, default=None, help="Override the tracking time, s.")
@click.option("--log", "log", default=None, metavar="FILE.mcap", help="Log here instead of the config's log_dir.")
@click.option("--json", "as_json", is_flag=True, help="Print the flight's metrics as one JSON object.")
@click.option("--live", "live_port", type=click.IntRange(1024, 65535), default=None, metavar="PORT",
              help="Serve the flight live to Foxglove (ws://127.0.0.1:PORT, e.g. 8765) while it flies.")
def fly_command(flight: str, duration: float | None, log: str | None, as_json: bool, live_port: int | None) -> int:
    """Fly a flight config: connect, preflight, arm, take off, track, land.

    Ctrl-C (or l) lands; a second Ctrl-C (or k) stops the motors at once. Exit status: 0 landed as planned or as
    asked, 1 failsafe, emergency stop, not started or the log failed, 2 bad input (an existing --log included),
    3 landed but degraded beyond the flight's bounds."""
    from groundstation.flightlog.mcap_log import SUBPROTOCOLS
    from groundstation.runtime.flight import Requests
    from groundstation.runtime.fly import fly

    log_path = writable_output(log, (".mcap",)) if log else None
    if live_port is not None:  # served from the writer process later, where a port in use was only a log event
        from groundstation.errors import SessionError
        from groundstation.mocap.zenoh_link import check_listenable

        try:
            check_listenable(f"tcp/127.0.0.1:{live_port}")
        except SessionError as exc:
            raise click.UsageError(f"--live {live_port}: {exc}") from None
    console = stderr_console()
    requests = Requests()
    # The status line is drawn by a thread of ours between control periods (LoopActivity), not by rich's
    # auto-refresh thread, whose rendering would take the GIL while a period computes.
    live = Live(console=console, auto_refresh=False, transient=True) if console.is_terminal else None
    activity = LoopActivity()
    latest: list = [None]
    done = threading.Event()

    def on_status(s):  # on the control thread: only keep the newest
        latest[0] = s

    def render():
        shown = None
        while not done.is_set():
            activity.wait_end(STATUS_S)
            s = latest[0]
            if s is None or s is shown or not activity.may_work(1e-3):  # a render takes ~0.5 ms
                continue
            shown = s
            live.update(status_text(s, console.width, KEYS_HINT), refresh=True)
            done.wait(STATUS_S)

    from groundstation.runtime.keys import KeyReader

    renderer = threading.Thread(target=render, name="status-line", daemon=True) if live is not None else None
    if live is not None:
        live.start()
        live.update("[bold]preflight[/]", refresh=True)  # rich's first render is slow: pay it before the flight
        renderer.start()
    try:
        with KeyReader(requests):
            if live_port is not None:
                click.echo(f"live: open Foxglove (or Lichtblick 1.22 or later), connect to ws://127.0.0.1:{live_port} "
                           f"(WebSocket subprotocol {' or '.join(SUBPROTOCOLS)})", err=True)
            result = fly(flight, duration=duration, log_path=log_path, requests=requests, on_status=on_status,
                         handle_signals=True, activity=activity, live_port=live_port)
            held = _hold_signals(LANDING_SIGNALS)
    finally:
        done.set()
        forget_lost_terminal()  # hung up in flight (the signal handler saw a live terminal) or after it
        if live is not None:
            renderer.join(2.0)
            live.stop()
    try:
        status = _report(flight, result, as_json)
    except OSError:  # stderr gone too (a terminal hung up): nobody to tell, the status says it
        status = _status(result)
    _end_on_signal(LANDING_SIGNALS, status, now=bool(held))
    return status


def _status(result) -> int:
    """The exit status of a flight that ended (see :func:`fly_command`)."""
    return EXIT_EMERGENCY if not result.nominal else EXIT_DEGRADED if result.degraded else 0


def _hold_signals(signals) -> list[int]:
    """From the flight's end (motors off, log finalized) until its summary is printed: ``signals`` are noted (the
    list returned), not acted on, so the summary is whole (ended at once, a Ctrl-C twice after a refused preflight
    left no summary at all; by default a SIGTERM or Ctrl-C then ended the process 143 or 130 after a summary saying
    "done": hostile campaigns)."""
    held: list[int] = []
    for s in signals:
        signal.signal(s, lambda signum, frame: held.append(signum))
    return held


def _end_on_signal(signals, status: int, now: bool = False) -> None:
    """After the summary: one of ``signals`` (or ``now``, one came while it printed) ends the process at once with
    the flight's ``status``, what was printed flushed; ignored, a shutdown that hangs (Zenoh closing) could not be
    cut short. Left installed to the process's end (:func:`groundstation.cli.main` restores the caller's handlers
    when called in-process)."""

    def handler(signum=None, frame=None):
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(status)

    if now:
        handler()
    for s in signals:
        signal.signal(s, handler)


def _report(flight: str, result, as_json: bool) -> int:
    """Print the flight's summary (stdout) and what went wrong (stderr); the exit status."""
    from groundstation.runtime.flight import operator_landing

    # The log's own failure is in the summary: a flight that landed as planned while its log writer hung exits 1,
    # and a script reading only the JSON must see why.
    summary = {"phase": result.phase, "reason": result.reason, "degraded": list(result.degraded),
               "log": str(result.log_path), "log_error": result.log_error, **asdict(result.metrics)}
    try:
        _print_summary(flight, summary, result, as_json)
    except OSError as exc:
        # Stdout on a full disk, closed, a pipe or terminal gone: one line, and the stderr lines below still say
        # why the flight ended (skipped with the summary, they left only "cannot print").
        with contextlib.suppress(OSError):
            click.echo(f"groundstation: cannot print the flight's summary ({exc.strerror or exc}); it is in the "
                       f"log {result.log_path}", err=True)
        stdout_lost()
    click.echo(f"log: {result.log_path}", err=True)
    if result.log_rejected:
        click.echo("groundstation: warning: messages the log writer rejected (counted, not written): " +
                   "; ".join(f"{k}: {n}" for k, n in result.log_rejected.items()), err=True)
    if result.log_error is not None:
        click.echo(f"groundstation: the log writer failed: {result.log_error} (what was written reads with "
                   f"groundstation replay, or log recover)", err=True)
    if not result.nominal:
        if result.log_error is None or result.phase != Phase.DONE or not (result.reason == "" or
                                                                           operator_landing(result.reason)):
            what = {Phase.ABORTED: "did not start", Phase.DONE: "landed early"}.get(result.phase,
                                                                                  f"ended in {result.phase}")
            click.echo(f"groundstation: the flight {what}: {result.reason}", err=True)
    elif result.degraded:
        click.echo(f"groundstation: the flight degraded beyond its bounds: {'; '.join(result.degraded)}", err=True)
    return _status(result)


def _print_summary(flight: str, summary: dict, result, as_json: bool) -> None:
    """The flight's summary on stdout: one JSON object, or a table."""
    if as_json:
        click.echo(json.dumps(json_safe(summary)))
        return
    table = Table(title=f"Flight {flight}", show_header=False)
    for k in ("phase", "reason", "pos_rmse_m", "max_pos_error_m", "max_orientation_error_deg",
              "max_roll_error_deg", "max_motor_fraction"):
        v = summary[k]
        table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    if result.degraded:
        table.add_row("degraded", "; ".join(result.degraded))
    loop = result.metrics.loop
    if loop is not None:
        table.add_row("loop", f"{loop.rate_hz:.0f} Hz, p99 start error {loop.start_error_ms_p99:.3f} ms, "
                              f"{loop.overruns} overruns")
    Console().print(table)


@click.group("log")
def log_group() -> None:
    """Flight log tools."""


@log_group.command("recover")
@click.argument("src", type=click.Path(dir_okay=False, exists=False))
@click.argument("dst", type=click.Path(dir_okay=False))
def recover_command(src: str, dst: str) -> int:
    """Copy every intact record of a truncated or damaged MCAP (after SIGKILL, a bad disk) into a finalized file,
    and say what was dropped."""
    from pathlib import Path

    from groundstation.flightlog.mcap_log import recover
    from groundstation.flightlog.salvage import log_file
    from groundstation.output import writing

    log_file(src)  # one line naming it unless a regular file: not found, a device (/dev/zero), a FIFO
    out = writable_output(dst, (".mcap",))
    with writing(out):
        counts = recover(src, out)
    for line in counts["warnings"]:
        click.echo(f"groundstation: warning: {src}: {line}", err=True)
    click.echo(json.dumps(counts))
    if counts["messages"] == 0:  # a copy of nothing is no recovered log: none is left to be taken for one
        Path(out).unlink()
        click.echo(f"groundstation: {src}: no intact message to recover; {out} not written", err=True)
        return 1
    click.echo(f"recovered: {out}", err=True)
    return 0


@click.command("mocap-bridge")
@click.option("--system", type=click.Choice(MOCAP_SYSTEMS), required=True, help="The mocap system's SDK.")
@click.option("--host", default="", help="Mocap server address (unused for mock).")
@click.option("--bodies", type=BodyList(), required=True, help="Comma-separated rigid body names to publish.")
@click.option("--endpoint", type=ListenEndpoint(), default="tcp/127.0.0.1:7448", show_default=True,
              help="Zenoh endpoint to listen on.")
@click.option("--key-prefix", type=KeyChunks("many"), default="mocap", show_default=True)
@click.option("--y-up", is_flag=True, help="Convert a y-up stream (OptiTrack default) to z-up.")
@click.option("--mock-bodies", type=MockBodies(), default="",
              help='Mock system bodies, e.g. "a(0,0,1,1,0,0,0)" (x,y,z,qw,qx,qy,qz).')
@click.option("--duration", type=FiniteFloat(min=0, min_open=True), default=None,
              help="Stop after this many seconds.")
@click.option("--tls-ca", default=None, type=click.Path(dir_okay=False, exists=True),
              help="TLS: the lab CA (PEM); the endpoint is then tls/HOST:PORT.")
@click.option("--tls-cert", default=None, type=click.Path(dir_okay=False, exists=True),
              help="TLS: this bridge's certificate (PEM), for mutual TLS.")
@click.option("--tls-key", default=None, type=click.Path(dir_okay=False, exists=True),
              help="TLS: this bridge's private key (PEM).")
@click.option("--key-file", default=None, type=click.Path(dir_okay=False),
              help="Authenticate every pose with this key (groundstation mocap-key; the flight's mocap.key_file).")
def mocap_bridge_command(system: str, host: str, bodies: str, endpoint: str, key_prefix: str, y_up: bool,
                         mock_bodies: str, duration: float | None, tls_ca: str | None, tls_cert: str | None,
                         tls_key: str | None, key_file: str | None) -> int:
    """Publish motion-capture poses on Zenoh (foxglove.PoseInFrame on <prefix>/<body>/pose)."""
    from groundstation.mocap.auth import load_key_file
    from groundstation.mocap.bridge import run_bridge
    from groundstation.mocap.zenoh_link import Security

    if (tls_cert is None) != (tls_key is None):
        raise UsageError("--tls-cert and --tls-key go together")
    security = Security(tls_ca, tls_cert, tls_key, mutual=tls_cert is not None) if tls_ca else None
    names = [b.strip() for b in bodies.split(",") if b.strip()]
    mac_key = load_key_file(key_file) if key_file else None
    stats = run_bridge(system, host, names, endpoint, key_prefix, y_up=y_up, mock_bodies=mock_bodies,
                       duration=duration, security=security, mac_key=mac_key)
    click.echo(json.dumps({"frames": stats.frames, "published": stats.published, "missing": stats.missing}))
    return 0


PEERS = {k.peer_protocol: k for k in KINDS.values() if k.peer is not None}
"""Backend kinds ``sim-peer`` can simulate, by protocol name."""


@click.command("sim-peer")
@click.argument("assembly", type=click.Path(dir_okay=False))
@click.option("--protocol", type=click.Choice(list(PEERS)), default="crtp", show_default=True,
              help="; ".join(f"{p}: {k.summary} (fly with backend {k.name})" for p, k in PEERS.items()) + ".")
@click.option("--port", type=click.IntRange(1024, 65535), default=19850, show_default=True,
              help="UDP port of module 0; module i listens on port + i.")
@click.option("--mocap", "endpoint", type=ListenEndpoint(), default="tcp/127.0.0.1:7448", show_default=True,
              help="Zenoh endpoint the virtual mocap listens on.")
@click.option("--body", type=BODY, default="assembly", show_default=True,
              help="Rigid body name (key mocap/<body>/pose).")
@click.option("--physics-hz", type=FiniteFloat(min=1, max=10000), default=None,
              help="Physics rate, Hz (default: the simulator's; 1000 with --firmware).")
@click.option("--platform", type=click.Choice(["cf2", "cf21bl", "bolt"]), default="bolt", show_default=True,
              help="crtp: the Crazyflie platform simulated (bolt and cf21bl must be asked to arm; cf2 arms itself).")
@click.option("--stock-firmware", is_flag=True,
              help="crtp: modules without the motor app (what the ground station must refuse).")
@click.option("--params", "param_file", type=click.Path(dir_okay=False), default=None,
              help="Start the modules with these firmware parameters set (a firmware_params/ file: modules "
                   "already configured); otherwise they have stock values.")
@click.option("--firmware", "firmware_binary", type=click.Path(dir_okay=False), default=None,
              help="crtp: run the real crazyflie-firmware, one process per module: a cf_sitl binary built by "
                   "firmware/crazyflie_sitl for --platform (physics then runs at the firmware's 1 kHz).")
@click.option("--state-dir", type=click.Path(file_okay=False), default=None,
              help="--firmware: where the modules keep their stored parameters and console logs (default: a "
                   "temporary directory; give one to keep stored parameters across runs).")
@click.option("--duration", type=FiniteFloat(min=0, min_open=True), default=None,
              help="Stop after this many seconds.")
@click.option("--mocap-key-file", default=None, type=click.Path(dir_okay=False),
              help="Authenticate the simulated mocap's poses with this key (the flight's mocap.key_file).")
def sim_peer_command(assembly: str, protocol: str, port: int, endpoint: str, body: str, physics_hz: float | None,
                     platform: str, stock_firmware: bool, param_file: str | None, firmware_binary: str | None,
                     state_dir: str | None, duration: float | None, mocap_key_file: str | None) -> int:
    """Simulate an assembly's modules behind their wire protocol on loopback UDP, with its pose on Zenoh.

    Fly it with a config whose backend is crazyflie (modules udp://127.0.0.1:PORT, PORT+1, ...) or mavlink
    (modules udpout:127.0.0.1:PORT, PORT+1, ...). SIGINT/SIGTERM stop the simulation.
    """
    import signal

    from groundstation.assembly.assembly_file import load_assembly
    from groundstation.firmware.params import load_param_file
    from groundstation.mocap.auth import load_key_file
    from groundstation.mocap.zenoh_link import pose_key
    from sim.module_peer import PeerConfig

    kind = PEERS[protocol]
    peer_class, scheme = load(kind.peer), kind.peer_scheme
    asm, _ = load_assembly(assembly)
    if port + asm.n - 1 > 65535:
        raise UsageError(f"--port: {port}: module {asm.n - 1} would listen on {port + asm.n - 1}, beyond 65535")
    params = tuple(load_param_file(param_file).items()) if param_file else ()
    extra = {}
    if firmware_binary is not None:
        if protocol != "crtp" or stock_firmware or param_file:
            raise UsageError("--firmware runs Crazyflie firmware (--protocol crtp), with the motor app and the "
                             "parameters it stores itself (set them with 'groundstation params --apply')")
        from sim.firmware_peer import FIRMWARE_PHYSICS_HZ, FIRMWARE_PRIORITY, FirmwareCrazyflies

        peer_class, extra = FirmwareCrazyflies, {"binary": firmware_binary, "state_dir": state_dir}
        physics_hz = physics_hz or FIRMWARE_PHYSICS_HZ
    peer = peer_class(asm, PeerConfig(port=port, mocap_endpoint=endpoint, mocap_key=pose_key("mocap", body),
                                      physics_hz=physics_hz or sim_physics_hz(), params=params, platform=platform,
                                      motor_app=not stock_firmware,
                                      mocap_mac_key=load_key_file(mocap_key_file) if mocap_key_file else None),
                      **extra)
    try:
        peer.open()
    except (OSError, ValueError) as exc:  # port taken; a parameter these modules do not have
        raise UsageError(f"{param_file}: {exc}" if param_file and isinstance(exc, ValueError) else str(exc)) from None
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: peer.stop_event.set())
    links = ", ".join(f"{scheme}{peer.config.host}:{port + i}" for i in range(asm.n))
    if firmware_binary:
        click.echo("firmware processes: " + (f"SCHED_FIFO {FIRMWARE_PRIORITY}" if peer.realtime_firmware else
                                             "normal priority (SCHED_FIFO not permitted here, or too many modules "
                                             "for the cores: their answers can come late on a busy host)"), err=True)
    click.echo(f"simulating {asm.n} modules ({protocol}) on {links}; pose on {endpoint}", err=True)
    try:
        peer.run_as_world(duration)
    finally:
        peer.close()
    click.echo(json.dumps({"packets": peer.packets, "simulated_s": peer.sim.time, "world_pauses": peer.pauses,
                           "realtime": peer.realtime}))
    return 0
