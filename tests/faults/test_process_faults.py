"""Fault table: the process, the operator and the resources of a flight (safety issue 20).

Each row injects its fault for real: a log path that exists or that a running flight writes, signals to a real
``groundstation fly`` process (SIGTERM before arming, twice in flight, SIGKILL), a crash of the control loop, a log
writer process that stops (SIGSTOP) or whose filesystem is frozen (fsfreeze), pose stamps that are not times through
the real writer, gains that degrade the flight. The outcome is defined: one line and exit 2 before anything opens;
or a log that is finalized (or finished by its writer), replays with the flight's end and its reason, and an exit
status that says what happened (0 nominal, 1 failsafe or not started, 3 degraded).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import pty
import select
import shutil
import signal
import subprocess
import sys
import termios
import threading
import time
from pathlib import Path

import pytest

from groundstation.flightlog.mcap_log import SOURCE_LIVE, WRITER_STALL_S
from groundstation.replay.analysis import COPIED_LIVE, NO_END, STILL_WRITTEN, analyse
from groundstation.replay.reader import open_log
from groundstation.runtime.fly import Faults, fly
from tests.faults.table import Fault, process_fault, rows
from tests.peers import ROOT
from tests.runtime.test_fly import config_with, read_log

AIRBORNE = ("takeoff", "settle", "track", "hold")
HUNG = "log writer failed: the log writer has taken none of its input for "


def _fly_process(cfg: Path, log: Path, *args: str) -> subprocess.Popen:
    """``groundstation fly`` in a process of its own, as an operator starts it; its output goes to files (its log
    writer inherits them, and one left hung would hold a pipe open): :func:`_ended` reads them."""
    paths = [cfg.with_name(f"{log.stem}.{k}") for k in ("out", "err")]  # beside the config: not on a frozen disk
    with open(paths[0], "w") as out, open(paths[1], "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "groundstation", "fly", str(cfg), "--log", str(log), "--json",
                                 *args], stdout=out, stderr=err, text=True, cwd=ROOT)
    proc.output_paths = paths
    return proc


def _ended(proc: subprocess.Popen, timeout: float = 120.0) -> tuple[str, str]:
    """Wait for a :func:`_fly_process`; its stdout and stderr."""
    proc.wait(timeout)
    return tuple(p.read_text() for p in proc.output_paths)


def _wait_until(done, proc: subprocess.Popen | None = None, what: str = "", timeout: float = 120.0) -> None:
    """Poll ``done()`` (a cap for a loaded machine, not a timing assertion); the flight process must not end first."""
    deadline = time.monotonic() + timeout
    while not done():
        assert proc is None or proc.poll() is None, f"ended before {what}"
        assert time.monotonic() < deadline, f"never {what}"
        time.sleep(0.05)


def _airborne(log: Path) -> bool:
    """The log being written already has a control period in the air (the writer flushes each second)."""
    with contextlib.suppress(Exception):  # not there yet, or cut in the middle of a chunk: not yet
        records = open_log(log).records(topics={"/control"})
        try:
            return any(rec.data.get("phase") in AIRBORNE for rec in records)
        finally:
            records.close()
    return False


def _writer_of(log: Path) -> int:
    """The process writing ``log`` (the flight's log writer: the only one holding it open)."""
    target = str(log.resolve())
    for pid in filter(str.isdigit, os.listdir("/proc")):
        if int(pid) == os.getpid():
            continue
        with contextlib.suppress(OSError):
            if any(os.readlink(f"/proc/{pid}/fd/{fd}") == target for fd in os.listdir(f"/proc/{pid}/fd")):
                return int(pid)
    raise AssertionError(f"no process writes {log}")


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split()[2] == "Z"  # a zombie has ended
    except OSError:
        return True


def _replayed(cli, log: Path) -> dict:
    code, out, err = cli("replay", str(log), "--json")
    assert code == 0, err
    (figures,) = json.loads(out)  # a list, one object per log
    return figures


# -- the log file ------------------------------------------------------------------------------------------------------
@process_fault("fly --log naming a file that exists",
               "one line naming --log, exit 2, the file untouched, nothing opened")
def f_log_path_exists(cli, tmp_path):
    log = tmp_path / "yesterday.mcap"
    log.write_bytes(b"yesterday's flight")
    code, out, err = cli("fly", str(config_with(tmp_path, endpoint="tcp/127.0.0.1:8657")), "--log", str(log))
    assert code == 2 and err.count("\n") == 1 and "--log" in err and "never overwritten" in err, err
    assert log.read_bytes() == b"yesterday's flight"


@process_fault("a second fly given the --log of a flight in progress",
               "the second refused (one line, exit 2); the first flies on (exit 0), its log whole")
def f_log_path_of_a_running_flight(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8658")
    log = tmp_path / "first.mcap"
    first = _fly_process(cfg, log, "--duration", "1")
    try:
        _wait_until(log.exists, first, "claimed its log")
        code, out, err = cli("fly", str(cfg), "--log", str(log))  # the same command, once more
        assert code == 2 and err.count("\n") == 1 and "never overwritten" in err, err
        out, err = _ended(first, 300)
    finally:
        first.kill()
    assert first.returncode == 0 and json.loads(out)["phase"] == "done", err
    r = _replayed(cli, log)
    assert r["complete"] and r["phase"] == "done" and r["reason"] == "" and r["periods"] > 250


@process_fault("fly started with 24 open files allowed (ulimit -n 24: soft and hard), and with the soft limit alone "
               "at 24",
               "hard: one line naming the limit and what a session needs, exit 2, no log (before: a panic in Zenoh's "
               "runtime and a traceback); soft only: raised, the flight flies, exit 0")
def f_too_few_file_descriptors(cli, tmp_path):
    import resource

    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8659")
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    for limits, name in (((24, 24), "hard"), ((24, hard), "soft")):
        log = tmp_path / f"{name}.mcap"
        proc = subprocess.run([sys.executable, "-m", "groundstation", "fly", str(cfg), "--log", str(log), "--json",
                               "--duration", "1"], capture_output=True, text=True, cwd=ROOT, timeout=300,
                              preexec_fn=lambda limits=limits: resource.setrlimit(resource.RLIMIT_NOFILE, limits))
        if name == "hard":
            assert proc.returncode == 2 and proc.stderr == (
                "groundstation: error: this process may open only 24 files (ulimit -n 24): a Zenoh session needs at "
                "least 48\n"), proc.stderr
            assert not log.exists()
        else:
            assert proc.returncode == 0 and json.loads(proc.stdout)["phase"] == "done", proc.stderr


# -- signals -----------------------------------------------------------------------------------------------------------
@process_fault("SIGTERM to fly before it arms (during its preflight)",
               "never armed; the log finalized, its end aborted with the reason naming SIGTERM, replayable; exit 1")
def f_sigterm_in_preflight(cli, tmp_path):
    log = tmp_path / "preflight.mcap"
    proc = _fly_process(config_with(tmp_path, endpoint="tcp/127.0.0.1:8659"), log)
    try:
        _wait_until(log.exists, proc, "claimed its log")  # past its input checks: opening, then preflight
        proc.send_signal(signal.SIGTERM)
        out, err = _ended(proc)
    finally:
        proc.kill()
    reason = "stopped by the operator in preflight (SIGTERM): never armed"
    assert proc.returncode == 1 and f"the flight did not start: {reason}" in err, err
    assert json.loads(out)["phase"] == "aborted" and "Traceback" not in err
    counts, _, _, _ = read_log(log)  # a seeking reader: the summary section is there (finalized)
    assert "/control" not in counts and counts["/flight/summary"] == 1
    r = _replayed(cli, log)
    assert r["complete"] and r["phase"] == "aborted" and r["reason"] == reason


@process_fault("Ctrl-C every 3 ms from the moment fly's log is written until it exits (in its preflight: an operator "
               "hammering Ctrl-C)",
               "never armed; the summary printed and the log finalized, both saying aborted by the operator in "
               "preflight; exit 1 (a signal used to interrupt the log's opening or the end's logging: 'interrupted', "
               "exit 130, no summary, in one CI run; now only the modules' own checks are interrupted)")
def f_ctrl_c_storm_in_preflight(cli, tmp_path):
    log = tmp_path / "storm.mcap"
    proc = _fly_process(config_with(tmp_path, endpoint="tcp/127.0.0.1:8678"), log)
    sent = 0
    try:
        # From its log's first bytes (its writer has started): interrupted while still connecting, before that, it
        # leaves no log and says so (exit 130).
        _wait_until(lambda: log.exists() and log.stat().st_size > 0, proc, "opened its log")
        while proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGINT)
                sent += 1
            time.sleep(0.003)
        out, err = _ended(proc)
    finally:
        proc.kill()
    reason = "stopped by the operator in preflight (SIGINT): never armed"
    assert sent >= 2 and proc.returncode == 1, (sent, proc.returncode, err)
    assert json.loads(out)["phase"] == "aborted" and json.loads(out)["reason"] == reason, out
    r = _replayed(cli, log)
    assert r["complete"] and r["phase"] == "aborted" and r["reason"] == reason


def _signalled_in_flight(cli, tmp_path, signals: list[signal.Signals], port: int, lands_on: signal.Signals):
    """``fly`` sent ``signals`` (0.3 s apart) once airborne; (exit code, stderr, its log replayed), the log's landing
    on ``lands_on`` checked."""
    log = tmp_path / "signalled.mcap"
    proc = _fly_process(config_with(tmp_path, endpoint=f"tcp/127.0.0.1:{port}"), log, "--duration", "2")
    try:
        _wait_until(lambda: _airborne(log), proc, "airborne")
        for i, sig in enumerate(signals):
            time.sleep(0.3 * (i > 0))
            proc.send_signal(sig)
        out, err = _ended(proc)
    finally:
        proc.kill()
    r = _replayed(cli, log)
    texts = [e["text"] for e in r["events"]]
    assert any(t.endswith(f"-> landing: operator land ({lands_on.name})") for t in texts), texts
    return proc.returncode, err, r


def _landed(code: int, err: str, r: dict, sig: signal.Signals) -> None:
    assert code == 0, err
    assert r["complete"] and r["phase"] == "done" and r["reason"] == f"operator land ({sig.name})", r
    assert any(e["text"] == "landing -> done: landed" for e in r["events"]), r["events"]


@process_fault("SIGTERM to fly in flight (a service manager stopping it)",
               "a landing, the log finalized with its reason operator land (SIGTERM); exit 0")
def f_sigterm_in_flight(cli, tmp_path):
    _landed(*_signalled_in_flight(cli, tmp_path, [signal.SIGTERM], 8660, signal.SIGTERM), signal.SIGTERM)


@process_fault("SIGTERM twice to fly in flight",
               "landing at the first, motors off at the second; the end (emergency, operator stop (SIGTERM)) in the "
               "log and in replay; exit 1")
def f_sigterm_twice_in_flight(cli, tmp_path):
    code, err, r = _signalled_in_flight(cli, tmp_path, [signal.SIGTERM] * 2, 8667, signal.SIGTERM)
    assert code == 1 and "the flight ended in emergency: operator stop (SIGTERM)" in err, err
    assert r["complete"] and r["phase"] == "emergency" and r["reason"] == "operator stop (SIGTERM)", r


@process_fault("SIGHUP twice to fly in flight, 0.3 s apart (an SSH session dropping: the kernel's hang-up and the "
               "shell's)",
               "a landing, never a stop (nobody is left to have asked for one); the log finalized with its reason "
               "operator land (SIGHUP); exit 0")
def f_sighup_twice_in_flight(cli, tmp_path):
    _landed(*_signalled_in_flight(cli, tmp_path, [signal.SIGHUP] * 2, 8668, signal.SIGHUP), signal.SIGHUP)


def _lands_on_the_first(cli, tmp_path, signals: list, port: int) -> None:
    """``signals`` 0.3 s apart in flight: the flight lands on the first, never stops at the others, and its log
    says so."""
    _landed(*_signalled_in_flight(cli, tmp_path, signals, port, signals[0]), signals[0])


@process_fault("Ctrl-C in flight, then SIGHUP and SIGTERM (the operator lands it, then their SSH session drops and "
               "the session's end follows)",
               "the landing goes on, never a stop: the SIGTERM after a hang-up is the session's, whatever began the "
               "landing; the log finalized with operator land (SIGINT); exit 0")
def f_ctrl_c_then_hangup_then_sigterm(cli, tmp_path):
    _lands_on_the_first(cli, tmp_path, [signal.SIGINT, signal.SIGHUP, signal.SIGTERM], 8676)


@process_fault("Ctrl-\\ (SIGQUIT) in flight",
               "a landing like Ctrl-C (by default it ends the process and the assembly falls); exit 0")
def f_sigquit_in_flight(cli, tmp_path):
    _lands_on_the_first(cli, tmp_path, [signal.SIGQUIT], 8673)


@process_fault("SIGUSR1 twice in flight, then one Ctrl-C, 0.3 s apart (a tool's kill -USR1, a log rotation; SIGUSR2 "
               "and SIGALRM alike)",
               "a landing (by default it ends the process and the assembly falls), never a stop: tools repeat it, "
               "and the operator's first Ctrl-C after it is their first request; exit 0")
def f_sigusr1_twice_then_ctrl_c_in_flight(cli, tmp_path):
    _lands_on_the_first(cli, tmp_path, [signal.SIGUSR1, signal.SIGUSR1, signal.SIGINT], 8674)


@process_fault("SIGXCPU in flight (the CPU-time limit: ulimit -t, systemd's LimitCPU=), then SIGPWR (a UPS's power "
               "failure) and a real-time signal, 0.3 s apart",
               "a landing (by default each ends the process and the assembly falls: 0.94 m up, no summary, in a "
               "hostile check), never a stop; the log finalized with operator land (SIGXCPU); exit 0")
def f_sigxcpu_sigpwr_and_a_realtime_signal_in_flight(cli, tmp_path):
    _lands_on_the_first(cli, tmp_path, [signal.SIGXCPU, signal.SIGPWR, signal.SIGRTMIN + 3], 8677)


@process_fault("SIGABRT in flight (systemd's WatchdogSec=, kill -ABRT), then SIGTRAP and SIGSYS, 0.3 s apart (sent "
               "with kill)",
               "a landing, never a stop (by default each ended the process 0.8-0.94 m up, the log 'no end of flight': "
               "hostile campaign 28); the log finalized with operator land (SIGABRT); exit 0")
def f_sigabrt_sigtrap_sigsys_in_flight(cli, tmp_path):
    _lands_on_the_first(cli, tmp_path, [signal.SIGABRT, signal.SIGTRAP, signal.SIGSYS], 8679)


@process_fault("fly --json with its stdout on a full device (/dev/full)",
               "the flight flies and lands as planned; one line on stderr says the summary could not be printed and "
               "where the log is; exit 0")
def f_stdout_full(cli, tmp_path):
    log = tmp_path / "full.mcap"
    err_path = tmp_path / "full.err"
    with open("/dev/full", "w") as full, err_path.open("w") as err:
        proc = subprocess.run([sys.executable, "-m", "groundstation", "fly",
                               str(config_with(tmp_path, endpoint="tcp/127.0.0.1:8675")), "--log", str(log), "--json",
                               "--duration", "1"], stdout=full, stderr=err, cwd=ROOT, timeout=300)
    err = err_path.read_text()
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert f"cannot print the flight's summary (No space left on device); it is in the log {log}" in err, err
    r = _replayed(cli, log)
    assert r["complete"] and r["phase"] == "done" and r["reason"] == ""


@process_fault("every command's stdout on a full device (/dev/full), closed (>&-) or a pipe whose reader went: "
               "bare groundstation, --version, enumerate 3, simulate --json",
               "full or closed: one line on stderr, 'cannot print the output (...)', exit 1 (before: a traceback "
               "on /dev/full, nothing and exit 0 with stdout closed); the pipe: exit 1, quiet (click's way: the "
               "reader chose to stop, as `| head` does)")
def f_stdout_of_every_command_lost(cli, tmp_path):
    commands = ([], ["--version"], ["enumerate", "3"],  # bare: its help (printed in an exception handler)
                ["simulate", str(ROOT / "configs/assemblies/toy_v2.json"), "--trajectory", "hover", "--duration",
                 "0.5", "--json"])
    for args in commands:
        for kind, why in (("full", "No space left on device"), ("closed", "stdout is closed"), ("pipe", None)):
            err_path = tmp_path / "err"
            read_end, write_end = os.pipe()
            os.close(read_end)  # the reader gone before anything is printed
            with contextlib.ExitStack() as stack:
                err = stack.enter_context(err_path.open("w"))
                out = stack.enter_context(open("/dev/full", "w")) if kind == "full" else \
                    write_end if kind == "pipe" else None
                proc = subprocess.run([sys.executable, "-m", "groundstation", *args], stdin=subprocess.DEVNULL,
                                      stdout=out, stderr=err, cwd=ROOT, timeout=300,
                                      preexec_fn=(lambda: os.close(1)) if kind == "closed" else None)
            os.close(write_end)
            text = err_path.read_text()
            assert proc.returncode == 1 and "Traceback" not in text and "Exception" not in text, (args, kind, text)
            if why is None:
                assert "error" not in text, (args, text)
            else:
                assert text.splitlines()[-1] == f"groundstation: error: cannot print the output ({why})", (args, text)


@process_fault("the terminal hanging up in flight (fly on a pseudo-terminal whose other end closes: an SSH "
               "connection dropping; the kernel's SIGHUP, then EIO on every write to it)",
               "a landing; the status line's last redraw and the summary's lines go nowhere instead of ending the "
               "command in a traceback; the log finalized with operator land (SIGHUP); exit 0")
def f_terminal_hangs_up_in_flight(cli, tmp_path):
    log = tmp_path / "hung_up.mcap"
    master, slave = pty.openpty()
    out_path = tmp_path / "hung_up.out"
    with out_path.open("w") as out:  # the summary as JSON, to see what the flight says; the rest on the terminal
        proc = subprocess.Popen([sys.executable, "-m", "groundstation", "fly",
                                 str(config_with(tmp_path, endpoint="tcp/127.0.0.1:8672")), "--log", str(log),
                                 "--json", "--duration", "2"], stdin=slave, stdout=out, stderr=slave, cwd=ROOT,
                                start_new_session=True,  # a session of its own, the terminal its controlling one
                                preexec_fn=lambda: fcntl.ioctl(0, termios.TIOCSCTTY, 0))
    os.close(slave)
    drained = threading.Event()

    def drain():  # a terminal emulator reads what is drawn; a full terminal would block the writer
        while not drained.is_set():
            if select.select([master], [], [], 0.05)[0]:
                with contextlib.suppress(OSError):
                    os.read(master, 65536)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        _wait_until(lambda: _airborne(log), proc, "airborne")
        drained.set()
        reader.join(5.0)
        os.close(master)  # the connection drops
        proc.wait(120)
    finally:
        proc.kill()
    summary = json.loads(out_path.read_text())
    assert proc.returncode == 0 and summary["phase"] == "done", (proc.returncode, summary)
    _landed(0, "", _replayed(cli, log), signal.SIGHUP)


@process_fault("Ctrl-Z (SIGTSTP) in flight, after SIGTTIN and SIGTTOU (a backgrounded fly touching its terminal)",
               "never stopped (by default each stops the process, the modules cut their motors and it falls): "
               "SIGTTIN and SIGTTOU ignored, SIGTSTP a landing like Ctrl-C; exit 0")
def f_sigtstp_in_flight(cli, tmp_path):
    stops = [signal.SIGTTIN, signal.SIGTTOU, signal.SIGTSTP]
    _landed(*_signalled_in_flight(cli, tmp_path, stops, 8669, signal.SIGTSTP), signal.SIGTSTP)


@process_fault("SIGTERM, Ctrl-C and SIGHUP, one every 2 ms, from the flight's summary until the process has "
               "exited (a service manager or an operator ending a flight that just landed)",
               "the exit status is the flight's (0: it landed as planned), the summary whole; by default a signal "
               "in that time ended the process 143 or 130 after a summary saying done")
def f_signals_after_the_flight(cli, tmp_path):
    log = tmp_path / "ended.mcap"
    proc = _fly_process(config_with(tmp_path, endpoint="tcp/127.0.0.1:8676"), log, "--duration", "1")
    sent = 0
    try:
        _wait_until(lambda: "log: " in proc.output_paths[1].read_text(), proc, "printed its summary")
        signals = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
        while proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):  # it has just exited
                proc.send_signal(signals[sent % 3])
                sent += 1
            time.sleep(0.002)
        out, err = _ended(proc)
    finally:
        proc.kill()
    assert sent >= 2, sent  # measured: 41-49 signals in the ~0.1 s the process takes to exit
    assert proc.returncode == 0, (proc.returncode, err)
    assert json.loads(out)["phase"] == "done" and "Traceback" not in err


@process_fault("replay and `log recover` of a log while its flight is under way",
               "replay: its writer is still writing it (not that its flight process died); recover warns that the "
               "copy is what was on disk then, and the copy's replay says it was taken mid-flight (before: it said "
               "the flight process had died); neither complete")
def f_replay_during_the_flight(cli, tmp_path):
    log, copy = tmp_path / "live.mcap", tmp_path / "copy.mcap"
    proc = _fly_process(config_with(tmp_path, endpoint="tcp/127.0.0.1:8671"), log)
    try:
        _wait_until(lambda: _airborne(log), proc, "airborne")
        r = _replayed(cli, log)
        code, out, err = cli("log", "recover", str(log), str(copy))
    finally:
        proc.kill()
        proc.wait(30)
    assert not r["complete"] and r["reason"] == STILL_WRITTEN, r["reason"]
    assert code == 0 and json.loads(out)["source_being_written"] is True, (code, err)
    assert f"{log}: {SOURCE_LIVE}" in err
    c = _replayed(cli, copy)
    assert not c["complete"] and c["reason"] == COPIED_LIVE, c["reason"]


@process_fault("the fly process killed (SIGKILL) in flight",
               "its writer finishes the file, noting the end is missing; replay: the last phase, the reason that the "
               "log has no end (never a plain end)")
def f_sigkill_in_flight(cli, tmp_path):
    log = tmp_path / "killed.mcap"
    proc = _fly_process(config_with(tmp_path, endpoint="tcp/127.0.0.1:8661"), log)
    try:
        _wait_until(lambda: _airborne(log), proc, "airborne")
        writer = _writer_of(log)
        proc.kill()
        proc.wait(30)
        _wait_until(lambda: _gone(writer), what="finished by its writer")
    finally:
        proc.kill()
    r = _replayed(cli, log)
    assert not r["complete"] and r["phase"] in AIRBORNE and r["reason"] == NO_END, (r["phase"], r["reason"])
    assert any(e["text"].startswith("the log ends without the flight's end") for e in r["events"])


# -- the loop ----------------------------------------------------------------------------------------------------------
@process_fault("an exception in the control loop (a bug in a period hook)",
               "motors off in that period; the crash, named, is the logged end (replay: emergency); the exception "
               "re-raised")
def f_loop_crash(cli, tmp_path):
    log = tmp_path / "crash.mcap"

    def bug(t):
        if t > 4.0:
            raise ZeroDivisionError("division by zero")

    with pytest.raises(ZeroDivisionError):
        fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8662"), duration=2.0, log_path=log, on_period=bug)
    r = _replayed(cli, log)
    assert r["complete"] and r["phase"] == "emergency"
    assert r["reason"] == "the control loop crashed: ZeroDivisionError: division by zero"
    assert r["timeline"][-1]["phase"] == "emergency"


# -- the log writer ---------------------------------------------------------------------------------------------------
def _hung_writer(cli, tmp_path, log: Path, cfg: Path, hang, resume) -> None:
    """Fly (a process of its own), hang its log writer in flight with ``hang(pid)``; the flight must see it within
    the watchdog's bound and land (exit 1). Then ``resume(pid)``: the writer, left alone, finishes the file."""
    proc = _fly_process(cfg, log, "--duration", "4")
    writer = None
    try:
        _wait_until(lambda: _airborne(log), proc, "airborne")
        writer = _writer_of(log)
        hang(writer)
        out, err = _ended(proc)
    finally:
        proc.kill()
        if writer is not None:
            resume(writer)
    summary = json.loads(out)
    assert proc.returncode == 1 and summary["phase"] == "done" and summary["reason"].startswith(HUNG), err
    assert f"> {WRITER_STALL_S:g} s: hung" in summary["reason"]
    assert f"> {WRITER_STALL_S:g} s: hung" in summary["log_error"]  # in the JSON too, whatever the phase says
    assert "the flight landed early: log writer failed" in err
    _wait_until(lambda: _gone(writer), what="finished by its writer, resumed")
    r = analyse(log)  # what it had been given, finished: the flight's end never reached it
    assert not r.complete and r.metrics.periods > 0 and r.metrics.reason == NO_END  # the file whole, not the flight


@process_fault("the log writer process stops (SIGSTOP) in flight",
               f"seen within {WRITER_STALL_S:g} s (the watchdog's bound), failsafe landing (on_log_failure), exit 1; "
               "resumed, the writer finishes the file")
def f_log_writer_stopped(cli, tmp_path):
    _hung_writer(cli, tmp_path, tmp_path / "stopped.mcap", config_with(tmp_path, endpoint="tcp/127.0.0.1:8663"),
                 lambda pid: os.kill(pid, signal.SIGSTOP), lambda pid: os.kill(pid, signal.SIGCONT))


@contextlib.contextmanager
def _loop_filesystem(tmp_path):
    """A 64 MiB ext4 filesystem on a loop device (root, mkfs.ext4, fsfreeze), mounted in ``tmp_path``."""
    if os.geteuid() != 0 or not all(shutil.which(t) for t in ("mkfs.ext4", "fsfreeze", "mount", "umount")):
        pytest.skip("freezing a filesystem needs root, mkfs.ext4 and fsfreeze")
    image, mount = tmp_path / "disk.img", tmp_path / "disk"
    mount.mkdir()
    with open(image, "wb") as fh:
        fh.truncate(64 << 20)
    made = subprocess.run(["mkfs.ext4", "-q", "-F", str(image)], capture_output=True)
    mounted = made.returncode == 0 and subprocess.run(["mount", "-o", "loop", str(image), str(mount)],
                                                      capture_output=True).returncode == 0
    if not mounted:
        pytest.skip("no loop device to mount a filesystem on")
    try:
        yield mount
    finally:
        subprocess.run(["fsfreeze", "-u", str(mount)], capture_output=True)  # never left frozen
        if subprocess.run(["umount", str(mount)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(mount)], capture_output=True)


@process_fault("the log's filesystem frozen (fsfreeze) in flight: the writer blocks in write",
               f"seen within {WRITER_STALL_S:g} s, failsafe landing, exit 1; thawed, the writer finishes the file "
               "(skipped without root or loop devices)")
def f_log_disk_frozen(cli, tmp_path):
    with _loop_filesystem(tmp_path) as disk:
        def freeze(pid):
            assert subprocess.run(["fsfreeze", "-f", str(disk)], capture_output=True).returncode == 0

        def thaw(pid):
            subprocess.run(["fsfreeze", "-u", str(disk)], capture_output=True)

        log = disk / "frozen.mcap"
        _hung_writer(cli, tmp_path, log, config_with(tmp_path, endpoint="tcp/127.0.0.1:8664"), freeze, thaw)
        kept = shutil.copy(log, tmp_path / "kept.mcap")
    kept = analyse(kept)  # the file whole and readable off the disk, without the flight's end
    assert kept.metrics.periods > 0 and kept.metrics.reason == NO_END and kept.warnings == ()


@process_fault("mocap samples logged with stamps that are not times for 1 s in flight (NaN, -1 s, inf, 1.7e12: "
               "milliseconds)",
               "rejected at the writer, counted and named in the log; the flight completes, its log whole (exit 0)")
def f_bad_pose_stamps(cli, tmp_path):
    faults = Faults()
    bad = [float("nan"), -1.0, float("inf"), 1.7e12]

    def stamps(t):
        faults.pose_stamp = bad[int(t * 10) % len(bad)] if 3.5 < t < 4.5 else None

    log = tmp_path / "stamps.mcap"
    res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8665"), duration=2.0, log_path=log, faults=faults,
              on_period=stamps)
    assert res.phase == "done" and res.nominal and res.log_error is None, res.reason
    assert set(res.log_rejected) == {"/mocap/assembly publish time"} and res.log_rejected[
        "/mocap/assembly publish time"] > 20  # ~100 Hz for 1 s
    r = _replayed(cli, log)
    assert r["complete"] and r["phase"] == "done"
    texts = [e["text"] for e in r["events"]]
    assert any(t.startswith("a message on /mocap/assembly is not written: its publish time") for t in texts)
    assert any(t.startswith("messages not written: /mocap/assembly publish time: ") for t in texts)


# -- a flight beyond its bounds ---------------------------------------------------------------------------------------
@process_fault("a lab's quality bound the flight cannot meet: attitude error p95 at most 0.1 deg (the mocap's own "
               "attitude noise; the dry run measures ~3 deg)",
               "the summary names the bound passed (attitude error p95 > 0.1 deg), exit 3")
def f_degraded_beyond_quality_bound(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8666")
    cfg.write_text(cfg.read_text() + "\n[quality]\nattitude_error_p95_deg = 0.1\n")
    log = tmp_path / "soft.mcap"
    code, out, err = cli("fly", str(cfg), "--duration", "2", "--log", str(log), "--json")
    summary = json.loads(out)
    assert code == 3 and summary["phase"] == "done" and summary["reason"] == "", err
    assert summary["degraded"][0].startswith("attitude error p95 ") and summary["degraded"][0].endswith("> 0.1 deg")
    assert "the flight degraded beyond its bounds: attitude error p95" in err
    _, _, logs, _ = read_log(log)
    assert any(b"degraded beyond the flight's bounds" in d for _, d in logs)


@process_fault("the log's directory removed in flight (rm -rf of the directory the flight writes to)",
               "the flight lands as planned; the log reported gone (not a path to a file that no longer exists), "
               "exit 1")
def f_log_directory_removed_in_flight(cli, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    removed = []

    def remove(t):
        if t > 1.0 and not removed:
            removed.append(t)
            shutil.rmtree(logs)

    res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8670"), duration=2.0, log_path=logs / "gone.mcap",
              on_period=remove)
    assert removed and res.phase == "done" and res.reason == "", res.reason
    assert not res.nominal and res.log_error.endswith("was removed or renamed during the flight"), res.log_error


@process_fault("the log file removed in flight and another flight's log copied to its path (a cleanup script, or "
               "another flight claiming the freed --log)",
               "the flight lands as planned; the result says the path leads to another file now, exit 1 (before: "
               "exit 0, 'log: PATH' naming the other flight's log, this one's lost without a word)")
def f_log_replaced_in_flight(cli, tmp_path):
    log, other = tmp_path / "replaced.mcap", tmp_path / "other.mcap"
    other.write_bytes(b"\x89MCAP0\r\n another flight's log")
    replaced = []

    def replace(t):
        if t > 1.0 and not replaced:
            replaced.append(t)
            log.unlink()
            shutil.copy(other, log)

    res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8671"), duration=2.0, log_path=log, on_period=replace)
    assert replaced and res.phase == "done" and res.reason == "", res.reason
    assert not res.nominal and res.log_error == (f"{log} is another file now: this flight's log was removed or "
                                                 f"replaced during the flight"), res.log_error


@process_fault("the log truncated to nothing in flight (`truncate -s 0`, `> file`, a cleanup script)",
               "the writer finds its file's start gone within a second and stops; the flight acts on the failed "
               "log (`on_log_failure`) and its result names it; never reported complete")
def f_log_truncated_in_flight(cli, tmp_path):
    """Before: the writer went on at its offset behind a hole, `fly` said done with no log error, exit 0, and
    neither `replay` nor `log recover` could open the file."""
    log = tmp_path / "cut.mcap"
    cut = []

    def truncate(t):
        if t > 1.5 and not cut:
            cut.append(t)
            os.truncate(log, 0)

    res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8671"), duration=2.0, log_path=log, on_period=truncate)
    assert cut and not res.nominal and "truncated or overwritten by another process" in (res.log_error or ""), \
        (res.phase, res.reason, res.log_error)
    assert res.phase == "done" and res.reason.startswith("log writer failed: OSError: the log file was truncated")
    named = [t for t, _, text in res.events if text.startswith("log writer failed")]
    assert named and named[0] - cut[0] < 1.5  # the writer checks at its once-a-second flush



@process_fault("the log cut to part of itself in flight (to 40 bytes, past its start; to half its length)",
               "the writer finds the stretch cut away (a hole where it wrote) at its next flush and stops; the flight "
               "acts on the failed log and its result names it; never reported complete (before: exit 0, done, 34-59 "
               "chunks unreadable)")
def f_log_cut_short_in_flight(cli, tmp_path):
    for keep in (lambda size: 40, lambda size: size // 2):
        log = tmp_path / f"cut-{len(list(tmp_path.glob('cut-*')))}.mcap"
        cut = []

        def truncate(t, log=log, cut=cut, keep=keep):
            if t > 1.5 and not cut:
                cut.append(keep(log.stat().st_size))
                os.truncate(log, cut[0])

        res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8681"), duration=2.0, log_path=log,
                  on_period=truncate)
        assert cut and not res.nominal and "truncated by another process" in (res.log_error or ""), \
            (res.phase, res.reason, res.log_error)
        assert res.reason.startswith("log writer failed: OSError: the log file was truncated"), res.reason


@process_fault("the log written over in place in flight (a longer log copied over it, as `cp` does)",
               "the writer finds the bytes it read back at its last flush changed and stops; the flight acts on the "
               "failed log and its result names it; never reported complete (before: exit 0, done: hostile campaign "
               "33)")
def f_log_written_over_in_flight(cli, tmp_path):
    other = tmp_path / "other.mcap"
    other.write_bytes(flight_log_bytes())
    log = tmp_path / "over.mcap"
    done = []

    def copy_over(t):
        if t > 1.5 and not done:
            done.append(t)
            with open(log, "r+b") as fh:  # truncated, then written
                fh.truncate(0)
                fh.write(other.read_bytes())

    res = fly(config_with(tmp_path, endpoint="tcp/127.0.0.1:8682"), duration=2.0, log_path=log, on_period=copy_over)
    assert done and not res.nominal and "by another process" in (res.log_error or ""), \
        (res.phase, res.reason, res.log_error)


def flight_log_bytes() -> bytes:
    """A whole flight's log, longer than a flight's first 1.5 s write."""
    from tests.flightlog.damage import flight_log

    return flight_log().read_bytes()

# -- long work ---------------------------------------------------------------------------------------------------
@process_fault("Ctrl-C (SIGINT to the process group, as a terminal sends it) while `enumerate 13` runs level 12 "
               "(seconds of compiled kernels that never look at signals)",
               "exit 130, levels 1 to 11 printed, the level it stopped in named, no traceback")
def f_ctrl_c_in_enumerate(cli, tmp_path):
    """The time to stop is printed, not asserted (measured 0.5-0.6 s; before: 6-22 s, then a numba traceback and
    exit 1)."""
    proc = subprocess.Popen([sys.executable, "-m", "groundstation", "enumerate", "13", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            cwd=ROOT, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while not lines or json.loads(lines[-1])["n"] < 11:  # level 12 starts now (~4 s of kernel)
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            lines.append(line)
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=120)
        print(f"stopped {time.monotonic() - t0:.2f} s after SIGINT")
    finally:
        proc.kill()
    rows_printed = [json.loads(line) for line in lines + out.splitlines()]
    assert proc.returncode == 130, err
    assert [r["n"] for r in rows_printed] == list(range(1, 12))  # the finished levels, and no level after
    assert "Traceback" not in err and "interrupted" in err
    assert "enumeration stopped in level 12; levels 1 to 11 are complete" in err


@process_fault("`enumerate 20` (no --sample) with 1.2 GB of address space (ulimit -v): a level too large for memory",
               "the finished levels printed, one line naming the level it stopped in, out of memory, and --sample, "
               "exit 1, no traceback (before: a MemoryError traceback)")
def f_enumerate_out_of_memory(cli, tmp_path):
    import resource

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (1_200_000_000, 1_200_000_000))

    proc = subprocess.run([sys.executable, "-m", "groundstation", "enumerate", "20", "--json"], capture_output=True,
                          text=True, cwd=ROOT, preexec_fn=limited, timeout=600)
    levels = [json.loads(line)["n"] for line in proc.stdout.splitlines()]
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert levels == list(range(1, len(levels) + 1)) and 9 <= len(levels) < 20, levels
    assert proc.stderr.strip().splitlines()[-1] == (
        f"groundstation: enumeration stopped in level {len(levels) + 1} (out of memory: sample the levels, --sample "
        f"N_n, as the paper's Algorithm 1 does); levels 1 to {len(levels)} are complete"), proc.stderr


@process_fault("SIGTERM, or in another run a hang-up, to `log recover` scanning a 4 GiB file (a flight log's header "
               "and metadata, then zeros: a long scan), once its copy exists",
               "it stops: one line 'interrupted (SIGTERM)' (or SIGHUP), exit 143 (129); no partial copy is left, so a "
               "retry runs (before: killed where it stood, a 1.7 kB unfinalized copy left that the retry refused to "
               "overwrite)")
def f_signal_to_log_recover(cli, tmp_path):
    from tests.flightlog.damage import chunks_of, flight_log

    log = flight_log()
    head = log.read_bytes()[:chunks_of(log)[0].start]  # header and metadata: the scan then walks the zeros
    src = tmp_path / "long.mcap"
    with open(src, "wb") as fh:
        fh.write(head)
        fh.truncate(4 << 30)  # sparse: no disk used
    for sig in (signal.SIGTERM, signal.SIGHUP):
        dst = tmp_path / f"copy-{sig.name}.mcap"
        proc = subprocess.Popen([sys.executable, "-m", "groundstation", "log", "recover", str(src), str(dst)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            _wait_until(dst.exists, proc, "created its copy")
            proc.send_signal(sig)
            out, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
        assert (proc.returncode, err.strip()) == (128 + sig, f"groundstation: interrupted ({sig.name})"), err
        assert not dst.exists() and "Traceback" not in err


@pytest.mark.parametrize("row", rows(__name__), ids=[f.id for f in rows(__name__)])
def test_fault(row: Fault, cli, tmp_path):
    row.run(cli, tmp_path)
