import os
import pty
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
