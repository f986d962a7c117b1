"""The motor app's C code: host unit tests, the packet vectors shared with Python, the Cortex-M4 build, and the
simulated modules' Python mirror of its gate checked against the compiled C."""

import ctypes
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from groundstation.backends import crtp_wire as wire
from sim.crazyflie_firmware import MotorApp
from tests.peers import ROOT

APP = ROOT / "firmware/crazyflie_app"
VECTORS = APP / "test/packet_vectors.txt"


def make(target: str, build_dir) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-s", "-C", str(APP), target, f"HOST_BUILD={build_dir}"], capture_output=True,
                          text=True, timeout=300)


def test_host_unit_tests_and_vectors(tmp_path):
    """gcc -Wall -Wextra -Werror: the pure logic and the glue (against our stub headers) pass their tests, and the
    C decodes every command vector the Python side encoded and encodes every state vector byte for byte."""
    run = make("host-test", tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    assert re.search(r"(\d+) checks, 0 failed", run.stdout)
    assert int(re.search(r"(\d+) checks", run.stdout).group(1)) > 100
    assert "20 command and 6 state vectors, 0 failures" in run.stderr  # claims count as commands, identities as states


def test_the_vector_file_is_what_python_encodes_and_c_encodes_what_python_decodes(tmp_path):
    assert VECTORS.read_text() == wire.vectors_text()  # regenerate: python -m groundstation.backends.crtp_wire
    run = make("host-test", tmp_path)
    assert run.returncode == 0, run.stderr
    c_identities = [bytes.fromhex(h) for h in re.findall(r"identity-c line=\d+ hex=([0-9a-f]+)", run.stdout)]
    assert len(c_identities) == len(wire.IDENTITY_VECTORS)
    for raw, sent in zip(c_identities, wire.IDENTITY_VECTORS, strict=True):
        got = wire.Identity.unpack(raw)
        assert (got.flags, got.token, got.session, got.uid, got.acc_mg) == (
            sent.flags, sent.token, sent.session, sent.uid, sent.acc_mg)
    c_states = [bytes.fromhex(h) for h in re.findall(r"state-c line=\d+ hex=([0-9a-f]+)", run.stdout)]
    assert len(c_states) == len(wire.STATE_VECTORS)
    for raw, sent in zip(c_states, wire.STATE_VECTORS, strict=True):
        got = wire.ModuleState.unpack(raw)
        assert (got.flags, got.sequence, got.counts, got.battery_mv, got.received, got.dropped) == (
            sent.flags, sent.sequence, sent.counts, sent.battery_mv, sent.received, sent.dropped)
        np.testing.assert_allclose(got.gyro, sent.gyro, rtol=1e-7)


def test_cross_compiles_for_the_cortex_m4_with_hard_float(tmp_path):
    if shutil.which("arm-none-eabi-gcc") is None:
        if os.environ.get("CI"):
            pytest.fail("arm-none-eabi-gcc missing: .ci/run installs gcc-arm-none-eabi")
        pytest.skip("arm-none-eabi-gcc not installed (Debian: gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    run = make("cross-check", tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    for obj in ("motor_protocol.arm.o", "motor_app.arm.o"):
        attrs = subprocess.run(["arm-none-eabi-readelf", "-A", str(tmp_path / obj)], capture_output=True,
                               text=True, check=True).stdout
        assert "Tag_CPU_arch: v7E-M" in attrs and "Tag_ABI_HardFP_use: SP only" in attrs, attrs
        assert "Tag_ABI_VFP_args: VFP registers" in attrs, attrs  # hard-float calling convention


class _Command(ctypes.Structure):
    _fields_ = [("sequence", ctypes.c_uint16), ("armed", ctypes.c_bool), ("token", ctypes.c_uint8),
                ("counts", ctypes.c_uint16 * 4)]


class _Owner(ctypes.Structure):
    _fields_ = [("session", ctypes.c_uint32), ("token", ctypes.c_uint8)]


class _Mailbox(ctypes.Structure):
    _fields_ = [("latest", _Command), ("has_command", ctypes.c_bool), ("accepted_tick", ctypes.c_uint32),
                ("received", ctypes.c_uint16), ("dropped", ctypes.c_uint16)]


def test_the_simulated_modules_gate_commands_exactly_as_the_c_app(tmp_path):
    """Random command streams (reordered, duplicated, late, across tick and sequence wrap, with locks and a
    supervisor that cannot fly) through the compiled C and through sim.crazyflie_firmware.MotorApp: the same
    acceptances, counters and forces."""
    lib_path = tmp_path / "libmotor.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O1", f"-I{APP / 'src'}", "-o", str(lib_path),
                    str(APP / "src/motor_protocol.c")], check=True, capture_output=True)
    lib = ctypes.CDLL(str(lib_path))
    lib.mp_mailbox_offer.restype = ctypes.c_bool
    lib.mp_mailbox_offer.argtypes = [ctypes.POINTER(_Mailbox), ctypes.POINTER(_Command), ctypes.c_uint32,
                                     ctypes.c_uint32]
    lib.mp_gate_forces.argtypes = [ctypes.POINTER(_Mailbox), ctypes.c_uint32, ctypes.c_uint32, ctypes.c_bool,
                                   ctypes.c_bool, ctypes.POINTER(ctypes.c_float)]
    lib.mp_owner_claim.restype = ctypes.c_bool
    lib.mp_owner_claim.argtypes = [ctypes.POINTER(_Owner), ctypes.POINTER(_Mailbox), ctypes.c_uint32, ctypes.c_uint32,
                                   ctypes.c_uint32]
    rng = np.random.default_rng(7)
    for _ in range(20):
        box, owner, py = _Mailbox(), _Owner(), MotorApp()
        lib.mp_mailbox_init(ctypes.byref(box))
        tick = int(rng.integers(0, 2**32))
        seq = int(rng.integers(0, 2**16))
        for _ in range(300):
            tick = (tick + int(rng.choice([0, 1, 4, 50, 99, 100, 101, 250]))) & 0xFFFFFFFF
            seq = (seq + int(rng.choice([1, 1, 1, 0, -1, -3, 2, 40000]))) & 0xFFFF
            counts = tuple(int(c) for c in rng.integers(0, 65536, 4))
            armed = bool(rng.random() < 0.8)
            if rng.random() < 0.05:  # a claim by one of three sessions (0: not a session)
                session = int(rng.integers(0, 3))
                assert lib.mp_owner_claim(ctypes.byref(owner), ctypes.byref(box), session, tick, 100) == \
                    py.claim(session, tick)
                assert (owner.session, owner.token, box.has_command) == (py.owner_session, py.owner_token,
                                                                        py.latest is not None)
            token = int(rng.choice([owner.token, owner.token, 0, 7]))
            c_cmd = _Command(seq, armed, token, (ctypes.c_uint16 * 4)(*counts))
            cmd = wire.MotorCommand(seq, armed, counts, token)
            # the app's handlePacket: the owner's command is offered, any other counted as dropped
            if py.accepts(cmd):
                accepted = lib.mp_mailbox_offer(ctypes.byref(box), ctypes.byref(c_cmd), tick, 100)
                assert accepted == py.offer(cmd, tick)
            else:
                assert owner.token == 0 or token != owner.token
                lib.mp_mailbox_drop(ctypes.byref(box))
                py.drop()
            assert (box.received, box.dropped) == (py.received, py.dropped)
            for later in (0, 99, 100):
                locked, can_fly = bool(rng.random() < 0.1), bool(rng.random() < 0.9)
                forces = (ctypes.c_float * 4)()
                lib.mp_gate_forces(ctypes.byref(box), (tick + later) & 0xFFFFFFFF, 100, locked, can_fly, forces)
                np.testing.assert_allclose(list(forces), py.forces((tick + later) & 0xFFFFFFFF, locked, can_fly),
                                           rtol=1e-6)
