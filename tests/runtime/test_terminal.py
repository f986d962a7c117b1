import contextlib
import os
import pty
import signal
import sys
import time

from groundstation.runtime.terminal import forget_lost_terminal, terminal_lost


def test_files_pipes_and_closed_descriptors_are_not_lost_terminals(tmp_path):
    with (tmp_path / "f").open("w") as f:
        assert not terminal_lost(f.fileno())
    r, w = os.pipe()
    try:
        assert not terminal_lost(w)
    finally:
        os.close(r)
        os.close(w)
    assert not terminal_lost(w)  # closed: EBADF, not a terminal that hung up
    master, slave = pty.openpty()
    try:
        assert not terminal_lost(slave)  # a live terminal
    finally:
        os.close(master)
        os.close(slave)


def test_a_hung_up_controlling_terminal_is_pointed_at_dev_null():
    pid, master = pty.fork()  # the child: a session leader on the pseudo-terminal, its controlling terminal
    if pid == 0:
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        with contextlib.suppress(OSError):
            os.read(0, 1)  # until the parent hangs up: end of file or EIO
        replaced = forget_lost_terminal()
        again = forget_lost_terminal()
        try:
            print("after the hang-up", flush=True)
            sys.stderr.write("and on stderr\n")
            sys.stderr.flush()
            ok = replaced == (0, 1, 2) and again == () and os.read(0, 1) == b""
        except OSError:
            ok = False
        os._exit(0 if ok else 1)
    time.sleep(0.5)  # the child ignores SIGHUP by then
    os.close(master)  # the terminal goes away
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
