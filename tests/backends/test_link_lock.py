"""One flight per link on this host: the lock a second process meets, all or none, gone with its holder."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from groundstation.backends.link_lock import LinkLocks, link_key, lock_dir
from groundstation.backends.mavlink import MavlinkBackend
from groundstation.errors import LinkError
from sim.mavlink_peer import SimulatedPx4
from tests import peers
from tests.peers import ASM, ROOT, U_MAX, stop_peer

HOLD = ("import sys\nfrom groundstation.backends.link_lock import LinkLocks\nlocks = LinkLocks(sys.argv[1:])\n"
        "locks.acquire()\nprint('held', flush=True)\nsys.stdin.read()\n")


def _holder(*uris: str) -> subprocess.Popen:
    """Another process holding ``uris``' locks until its stdin closes."""
    # Its temp and runtime directories elsewhere (another shell): the lock is where ours is all the same.
    env = {**os.environ, "TMPDIR": "/var/tmp", "XDG_RUNTIME_DIR": "/var/tmp"}
    proc = subprocess.Popen([sys.executable, "-c", HOLD, *uris], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, cwd=ROOT, env=env)
    assert proc.stdout.readline() == "held\n"
    return proc


def test_a_link_another_process_holds_is_refused_naming_it_and_the_holder():
    holder = _holder("udp://127.0.0.1:19850")
    try:
        with pytest.raises(LinkError, match=rf"^UDP://127.0.0.1:19850 is in use by another flight on this host "
                                            rf"\(pid {holder.pid}\)"):
            LinkLocks([" UDP://127.0.0.1:19850"]).acquire()  # the same link, however it is spelled in case
    finally:
        holder.communicate("")
    locks = LinkLocks(["udp://127.0.0.1:19850"])
    locks.acquire()  # released when its holder exited
    locks.release()
    assert lock_dir().stat().st_mode & 0o777 == 0o700  # per user: no other account can hold or fake a lock


def _own_interface_addresses() -> list[str]:
    """This host's non-loopback IPv4 address its default route leaves by (a UDP socket's connect sends nothing);
    none on a machine without a route."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: only the route is looked up
        except OSError:
            return []
        address = s.getsockname()[0]
    return [] if address.startswith("127.") else [address]


def test_a_link_spelled_another_way_is_the_same_link():
    """A second flight naming the held modules by another spelling of their links is refused (it passed before,
    and only the modules' own checks kept it off: hostile campaign 30)."""
    for spellings in (["udp://127.0.0.1:19852", "udp://localhost:19852/1", " UDP://127.0.0.1:19852/"],
                      ["udpout:127.0.0.1:14590", "udpout:localhost:14590", "tcp:127.0.0.1:14590"],
                      ["tcp:[::1]:5760", "tcp:[0:0::1]:5760", "tcp:127.0.0.1:5760"],
                      # the old numeric forms the link's resolver takes, the unspecified address, a trailing dot
                      # (hostile campaign 31: each passed the lock)
                      ["udp://127.1:19852", "udp://0x7f000001:19852", "udp://2130706433:19852", "udp://0177.0.0.1:19852",
                       "udp://0.0.0.0:19852", "udp://0:19852", "udp://127.0.0.1.:19852", "udp://[::ffff:127.0.0.1]:19852",
                       "udp://127.0.0.1:19852"],
                      ["radio://0/80/2M/E7E7E7E7E7", "radio://1/80/2M", "radio://0/80/250K/00E7E7E7E7E7"]):
        assert len({link_key(u) for u in spellings}) == 1, spellings
    assert link_key("radio://0/80/2M/E7E7E7E7E8") != link_key("radio://0/80/2M/E7E7E7E7E7")
    assert link_key("udp://127.0.0.1:19852") != link_key("udp://127.0.0.1:19853")
    assert link_key("/dev/ttyACM0:57600") == "serial:/dev/ttyACM0"  # a device's name keeps its case
    assert link_key("udp://10.0.0.5:19852") == "ip:10.0.0.5:19852"
    hosts = {line.split()[1] for line in Path("/etc/hosts").read_text().splitlines()
             if line.split()[:1] == ["127.0.0.1"] and len(line.split()) > 1}
    for name in hosts:  # a name /etc/hosts gives this host (the link resolves it so)
        assert link_key(f"udp://{name}:19852") == link_key("udp://127.0.0.1:19852"), name
    for address in _own_interface_addresses():  # a module served here answers on them too (campaign 33)
        assert link_key(f"udp://{address}:19852") == link_key("udp://127.0.0.1:19852"), address
    holder = _holder("udp://127.0.0.1:19852")
    try:
        with pytest.raises(LinkError, match="is in use by another flight on this host"):
            LinkLocks(["udp://localhost:19852/1"]).acquire()
    finally:
        holder.communicate("")


def test_links_are_taken_all_or_none():
    holder = _holder("udp://127.0.0.1:2")
    try:
        with pytest.raises(LinkError, match="udp://127.0.0.1:2 is in use"):
            LinkLocks(["udp://127.0.0.1:1", "udp://127.0.0.1:2"]).acquire()
        free = LinkLocks(["udp://127.0.0.1:1"])
        free.acquire()  # the first link's lock was given back when the second was refused
        free.release()
    finally:
        holder.communicate("")


def test_a_killed_holder_leaves_no_stale_lock():
    holder = _holder("radio://0/80/2M/E7E7E7E701")
    holder.send_signal(signal.SIGKILL)
    holder.wait(10)
    locks = LinkLocks(["radio://0/80/2M/e7e7e7e701"])
    locks.acquire()
    locks.release()


def test_a_px4_backend_on_held_links_sends_nothing():
    """The second flight is refused before it opens a socket: the vehicle hears no packet from it."""
    peer, th = peers.start_peer(SimulatedPx4, 14654, 7431)
    links = [f"udpout:127.0.0.1:{14654 + i}" for i in range(ASM.n)]
    holder = _holder(*links)
    try:
        heard = peer.packets
        with pytest.raises(LinkError, match=f"{links[0]} is in use by another flight on this host"):
            MavlinkBackend(links, U_MAX, ASM.module_rotations).connect()
        time.sleep(0.3)  # anything it had sent would have arrived by now
        assert peer.packets == heard
    finally:
        holder.communicate("")
        stop_peer(peer, th)


def test_params_on_links_a_flight_holds_is_refused(cli, tmp_path):
    """`params` takes the links' locks as a flight does: it never reads or writes the parameters of modules a flight
    on this host holds (hostile campaign 33: `params --apply` wrote into airborne modules)."""
    from tests.runtime.test_fly import sitl_config

    cfg = sitl_config(tmp_path, "crazyflie", 19856, "tcp/127.0.0.1:7436")
    holder = _holder("udp://localhost:19857")  # the flight holds module 1's link, spelled its way
    try:
        code, out, err = cli("params", str(cfg), "--apply")
    finally:
        holder.communicate("")
    assert code != 0 and err.count("\n") == 1 and "udp://127.0.0.1:19857 is in use by another flight on this " \
        f"host (pid {holder.pid})" in err, err


def test_a_lock_directory_another_account_could_write_is_refused(tmp_path, monkeypatch):
    """The lock directory's name is known to every account: one made first by someone else (or opened to others,
    or a link to elsewhere) could hold or swap the locks, so it is refused, naming it; a lock file replaced by a link
    is never followed."""
    monkeypatch.setenv("GROUNDSTATION_OTHER_HOST_LOCKS", str(tmp_path))
    directory = lock_dir()
    directory.mkdir(mode=0o777)
    directory.chmod(0o777)  # past the umask: anyone may write it
    with pytest.raises(LinkError, match=r"groundstation-links-\d+ is not this user's alone .*mode 777"):
        LinkLocks(["udp://127.0.0.1:19852"]).acquire()
    directory.rmdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir(mode=0o700)
    directory.symlink_to(elsewhere)
    with pytest.raises(LinkError, match="a link"):
        LinkLocks(["udp://127.0.0.1:19852"]).acquire()
    directory.unlink()
    locks = LinkLocks(["udp://127.0.0.1:19852"])
    locks.acquire()
    locks.release()
    target = tmp_path / "victim.txt"
    target.write_text("kept")
    for lock_file in directory.iterdir():
        lock_file.unlink()
        lock_file.symlink_to(target)
    with pytest.raises(LinkError, match="cannot lock udp://127.0.0.1:19852"):
        LinkLocks(["udp://127.0.0.1:19852"]).acquire()
    assert target.read_text() == "kept"
