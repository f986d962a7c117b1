"""The end of every flight is in its log (landings, emergencies, a crash of the loop, a refused preflight, the
operator before arming), replayed as it was; a log is never overwritten; a flight degraded beyond its bounds says
so."""

import dataclasses
import json
import math
import socket

import pytest

from groundstation.errors import PreflightError, SessionError, UsageError
from groundstation.replay.analysis import NO_END, analyse
from groundstation.runtime import fly as fly_module
from groundstation.runtime.flight import QualityBounds, Requests, degradation, operator_landing
from groundstation.runtime.fly import Faults, fly, prepare
from groundstation.runtime.loop import LoopSummary
from groundstation.runtime.metrics import FlightMetrics, FlightSummary
from tests.runtime.test_fly import config_with, read_log


def _summary(log) -> dict:
    counts, _, _, _ = read_log(log)
    assert counts.get("/flight/summary") == 1
    from mcap.reader import make_reader

    with open(log, "rb") as fh:
        return [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(topics=["/flight/summary"])][0]


# -- the log file ------------------------------------------------------------------------------------------------
def test_an_existing_log_is_refused_before_anything_opens(tmp_path):
    log = tmp_path / "old.mcap"
    log.write_bytes(b"yesterday's flight")
    with pytest.raises(UsageError, match="--log .*old.mcap: the file exists; a flight log is never overwritten"):
        fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7655"), log_path=log)
    assert log.read_bytes() == b"yesterday's flight"


def test_auto_named_logs_of_one_second_get_new_names(tmp_path, monkeypatch):
    cfg = config_with(tmp_path, **{'log_dir = "../../out/flights"': 'log_dir = "logs"'})
    monkeypatch.setattr(fly_module.time, "strftime", lambda fmt: "flight-20261201-120000")
    names = [prepare(cfg).log_file.name for _ in range(3)]
    assert names == ["flight-20261201-120000.mcap", "flight-20261201-120000-1.mcap", "flight-20261201-120000-2.mcap"]
    assert all((tmp_path / "logs" / n).exists() for n in names)


def test_a_flight_that_fails_before_its_log_opens_leaves_no_file(tmp_path):
    log = tmp_path / "x.mcap"
    with socket.socket() as taken:  # the endpoint the ground station would listen on is in use
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("127.0.0.1", 7656))
        taken.listen()
        cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:7656", **{"latency_s = 0.005": "latency_s = 0.005\n"
                                                                                          "listen = true"})
        with pytest.raises(SessionError, match="cannot listen on tcp/127.0.0.1:7656: Address already in use"):
            fly(cfg, log_path=log)
    assert not log.exists()  # the claim is released: the same --log works next time


# -- the end, in the log ----------------------------------------------------------------------------------------------
def test_a_crash_of_the_loop_is_the_logged_end(tmp_path):
    log = tmp_path / "crash.mcap"

    def crash(t):
        if t > 4.0:
            raise RuntimeError("a bug in a hook")

    with pytest.raises(RuntimeError, match="a bug in a hook"):
        fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7650"), duration=2.0, log_path=log, on_period=crash)
    end = _summary(log)
    assert end["phase"] == "emergency" and end["reason"] == "the control loop crashed: RuntimeError: a bug in a hook"
    _, _, _, motors = read_log(log)
    assert motors[-1][1]["motors_off"] and motors[-1][1]["phase"] == "emergency"  # the last record is the end
    r = analyse(log)
    assert r.complete and r.metrics.phase == "emergency" and r.metrics.reason == end["reason"]
    assert r.timeline[-1][1] == "emergency" and r.metrics.periods > 250


def test_a_refused_preflight_is_the_logged_end(tmp_path):
    log = tmp_path / "pre.mcap"
    with pytest.raises(PreflightError, match="mocap does not see"):
        fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7651"), log_path=log, faults=Faults(mocap_paused=True))
    end = _summary(log)
    assert end["phase"] == "aborted" and end["reason"].startswith("preflight failed: mocap does not see")
    r = analyse(log)  # no control period, and still a replay: its events and its end
    assert r.complete and r.metrics.phase == "aborted" and r.metrics.reason == end["reason"]
    assert r.metrics.periods == 0 and r.timeline == [(0.0, "aborted")]


def test_the_operator_before_arming_ends_the_flight_unarmed(tmp_path):
    log = tmp_path / "asked.mcap"
    requests = Requests(source="SIGTERM")
    requests.land.set()  # asked before the flight got anywhere
    res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7652"), log_path=log, requests=requests)
    assert res.phase == "aborted" and res.reason == "stopped by the operator in preflight (SIGTERM): never armed"
    assert not res.nominal and math.isnan(res.metrics.pos_rmse_m)
    counts, _, _, _ = read_log(log)
    assert "/control" not in counts and _summary(log)["reason"] == res.reason
    assert analyse(log).metrics.reason == res.reason


def test_the_operator_landing_names_the_signal():
    requests = Requests()
    assert requests.why("operator land") == "operator land"
    requests.source = "SIGHUP"
    assert requests.why("operator land") == "operator land (SIGHUP)"
    assert operator_landing("operator land") and operator_landing("operator land (SIGHUP)")
    assert not operator_landing("operator landing gear") and not operator_landing("")


def test_a_log_without_its_end_never_replays_as_a_complete_end(tmp_path):
    """A log cut before the flight's summary (the process killed): the last phase, and a reason saying so."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    log = tmp_path / "flown.mcap"
    fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:7653"), duration=1.0, log_path=log)
    cut = tmp_path / "no-end.mcap"  # the same records up to the middle of the tracking, finalized
    with open(log, "rb") as fh, open(cut, "wb") as out:
        reader = make_reader(fh)
        summary = reader.get_summary()
        w = Writer(out)
        w.start(profile="", library=reader.get_header().library)
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        sids = {s.id: w.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        cids = {c.id: w.register_channel(c.topic, c.message_encoding, sids.get(c.schema_id, 0))
                for c in summary.channels.values()}
        for _, ch, m in reader.iter_messages():
            if ch.topic == "/control" and json.loads(m.data)["phase"] == "track":
                break
            w.add_message(cids[ch.id], m.log_time, m.data, m.publish_time)
        w.finish()
    r = analyse(cut)
    assert not r.complete and r.timeline[-1][1] == "settle" and r.metrics.phase == "settle"  # whole file, no end
    assert r.metrics.reason == NO_END


# -- degraded beyond the bounds ---------------------------------------------------------------------------------------
def _figures(**changes) -> FlightSummary:
    base = FlightSummary.of(FlightMetrics(2).result(), realtime_factor=1.0, planned_s=10.0, crashed=False, stalls=0,
                            loop=LoopSummary(1000, 250.0, 0, False, 0.1, 0.2, 0.3, 0.1, 0.2, ()))
    return dataclasses.replace(base, **changes)


def test_degradation_names_each_bound_passed():
    b = QualityBounds()
    nominal = _figures(orientation_error_p95_deg=8.7, max_orientation_error_deg=23.0, saturation_fraction=(0.0, 0.25))
    assert degradation(nominal, b) == ()  # --duration 1: the figure-8 entered and left within a second
    assert degradation(_figures(), b) == ()  # never airborne: NaN figures are not judged
    late = LoopSummary(1000, 250.0, 300, False, 0.1, 0.2, 0.3, 0.1, 0.2, ())
    out = degradation(_figures(orientation_error_p95_deg=31.0, max_orientation_error_deg=50.0,
                               saturation_fraction=(0.1, 0.6), loop=late), b)
    assert out == ("attitude error p95 31.0 deg > 15 deg", "max attitude error 50.0 deg > 45 deg",
                   "module 1 rotors at a bound 60% of the airborne time > 50%",
                   "300 of 1000 control periods late (30% > 25%)")
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.max_attitude_error_deg = 90.0


def test_a_flight_beyond_its_bounds_says_so_in_its_result_and_log(tmp_path):
    """The figures a nominal dry run really has, judged against bounds it cannot meet."""
    log = tmp_path / "tight.mcap"
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:7654")
    cfg.write_text(cfg.read_text() + "\n[quality]\nmax_attitude_error_deg = 1e-3\n")  # the p95 bound, untouched, holds
    res = fly(cfg, duration=1.0, log_path=log)
    assert res.phase == "done" and res.reason == "" and res.nominal  # it flew its plan...
    assert any(d.startswith("max attitude error ") and d.endswith("> 0.001 deg") for d in res.degraded)
    assert _summary(log)["degraded"] == list(res.degraded)
    _, _, logs, _ = read_log(log)
    assert any(b"degraded beyond the flight's bounds: max attitude error" in d for _, d in logs)


def test_signals_land_then_stop_and_before_the_loop_interrupt():
    """Real signals to this process: the first asks to land (named), the second stops, but a hang-up never does
    (nor a SIGTERM after it);
    in a wait that looks at no request (nothing armed) the second also interrupts it, once. Ctrl-Z (SIGTSTP) is
    Ctrl-C; SIGTTIN and SIGTTOU are ignored (each would stop the process)."""
    import os
    import signal

    for started_first in (False, True):
        requests, waits = Requests(), fly_module._Waits()
        if started_first:
            waits.open = False
        restore = fly_module._install_signals(requests, waits)
        try:
            os.kill(os.getpid(), signal.SIGTTIN)
            os.kill(os.getpid(), signal.SIGTTOU)
            assert not requests.land.is_set()
            os.kill(os.getpid(), signal.SIGHUP)
            assert requests.land.is_set() and requests.source == "SIGHUP"
            os.kill(os.getpid(), signal.SIGHUP)
            os.kill(os.getpid(), signal.SIGTERM)  # a session's end after the hang-up
            assert not requests.stop.is_set() and requests.source == "SIGHUP"
            # Nobody asked for the hang-up's landing: the first Ctrl-Z (or Ctrl-C) after it only lands, the second
            # stops.
            os.kill(os.getpid(), signal.SIGTSTP)
            assert not requests.stop.is_set() and requests.source == "SIGTSTP"
            if started_first:
                os.kill(os.getpid(), signal.SIGTSTP)
            else:
                with pytest.raises(KeyboardInterrupt):
                    os.kill(os.getpid(), signal.SIGTSTP)
            assert requests.stop.is_set() and requests.why("operator stop") == "operator stop (SIGTSTP)"
            os.kill(os.getpid(), signal.SIGINT)  # raised once: a third signal never interrupts the end
            with pytest.raises(KeyboardInterrupt), waits.interruptible():
                os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
            assert not waits.open
        finally:
            restore()
    for first in (signal.SIGINT, signal.SIGTERM):  # the landing begun by another signal: the hang-up still counts
        requests, waits = Requests(), fly_module._Waits()
        waits.open = False
        restore = fly_module._install_signals(requests, waits)
        try:
            os.kill(os.getpid(), first)
            os.kill(os.getpid(), signal.SIGHUP)
            os.kill(os.getpid(), signal.SIGTERM)
            assert requests.land.is_set() and not requests.stop.is_set(), first
        finally:
            restore()
