import os
import pty
import signal
import time

from groundstation.runtime.flight import Requests
from groundstation.runtime.keys import KeyReader


def test_keys_in_a_real_terminal():
    master, slave = pty.openpty()
    with os.fdopen(slave, "r") as tty_in:
        req = Requests()
        with KeyReader(req, tty_in):
            os.write(master, b"x")
            time.sleep(0.3)
            assert not req.land.is_set() and not req.stop.is_set()
            os.write(master, b"l")
            time.sleep(0.3)
            assert req.land.is_set() and not req.stop.is_set()
            os.write(master, b"k")
            time.sleep(0.3)
            assert req.stop.is_set()
    os.close(master)


def test_inactive_without_a_terminal(tmp_path):
    with (tmp_path / "f").open("w+") as not_a_tty, KeyReader(Requests(), not_a_tty) as reader:
        assert reader._thread is None


def test_closed_or_absent_stdin_runs_without_keys(tmp_path, monkeypatch):
    monkeypatch.setattr("sys.stdin", None)  # what Python gives a process started with stdin closed
    with KeyReader(Requests()) as reader:
        assert reader._thread is None
    closed = (tmp_path / "f").open("w+")
    closed.close()
    with KeyReader(Requests(), closed) as reader:
        assert reader._thread is None


def test_a_terminal_that_hangs_up_ends_the_reader_not_the_flight():
    master, slave = pty.openpty()
    with os.fdopen(slave, "r") as tty_in:
        req = Requests()
        with KeyReader(req, tty_in) as reader:
            os.close(master)  # the SSH connection or the terminal window goes away
            reader._thread.join(5.0)
            assert not reader._thread.is_alive()  # ended, not spinning on a readable end of file
        assert not req.land.is_set() and not req.stop.is_set()


def test_keys_come_back_after_the_flight_ran_in_the_background():
    """Ctrl-Z stops a wrapper script around ``fly``; its shell resumes it behind another job: the terminal refuses
    reads from the background (EIO, SIGTTIN ignored as in flight). After ``fg`` the keys work again."""
    pid, master = pty.fork()  # the child: a session leader on the pseudo-terminal, its controlling terminal
    if pid == 0:
        signal.signal(signal.SIGTTOU, signal.SIG_IGN)
        reader_pid = os.fork()
        if reader_pid == 0:
            os.setpgid(0, 0)  # a process group of its own: the background
            signal.signal(signal.SIGTTIN, signal.SIG_IGN)
            req = Requests()
            with KeyReader(req, os.fdopen(0, closefd=False)) as reader:  # (pytest replaces sys.stdin)
                os.write(1, b"R")  # ready; keys typed now wait in the terminal
                time.sleep(0.5)  # reads refused meanwhile
                refused = reader._thread.is_alive()
                os.tcsetpgrp(0, os.getpgrp())  # fg
                landed = req.land.wait(10.0)
            os._exit(0 if refused and landed else 1)
        _, status = os.waitpid(reader_pid, 0)
        os._exit(os.waitstatus_to_exitcode(status))
    try:
        seen = b""
        while b"R" not in seen:
            seen += os.read(master, 64)
        os.write(master, b"l")
        _, status = os.waitpid(pid, 0)
    finally:
        os.close(master)
    assert os.waitstatus_to_exitcode(status) == 0
