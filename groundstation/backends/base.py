"""The Backend protocol: what the flight loop needs from modules, simulated or real (commands in, state out).

Implemented by ``sim`` (PyBullet), the Crazyflie and MAVLink backends, and an in-package fake.
Motor commands are rotor inputs ``u = Omega^2`` in rad^2/s^2, in assembly rotor order (module-major, q = 1..4);
a backend converts them to its wire format at its edge and never sends more than ``u_max``. A flight ends with
:meth:`Backend.disarm` after a normal landing (the modules can fly again) and with :meth:`Backend.emergency_stop`
on every other path (real modules latch it until they are rebooted).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Protocol, Self, runtime_checkable

import numpy as np

from groundstation.control.state import RigidState
from groundstation.estimation.measurement import PoseMeasurement


@dataclass(frozen=True)
class PreflightReport:
    ok: bool
    issues: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class Telemetry:
    stamp: float
    """Backend time, s."""
    link_ok: bool
    """All modules reachable."""
    motors: np.ndarray = field(repr=False)
    """(4n,) rotor inputs last applied, rad^2/s^2."""
    battery_v: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    """Per-module battery voltage, V (empty when unknown)."""
    gyro: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    """Body angular rate from the modules' IMUs (their mean), rad/s, body frame (empty when not streamed). Mocap
    gives the pose; differentiating it for the rate is too late and too noisy for the attitude loop."""
    gyro_age_s: float = 0.0
    """How long before this telemetry the oldest module reading in ``gyro`` arrived, s (0 where the gyros are read
    when asked, as in the simulator): beyond a few stream intervals the rate is old news, not the rate now."""
    module_gyros: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    """(n, 3) each module's gyro rotated into the body frame, rad/s (a rigid body: all alike up to noise and their
    delays; empty when not streamed)."""
    module_gyro_ages_s: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    """(n,) how long before this telemetry each module's reading in ``module_gyros`` arrived, s (inf for a module
    taken out of the flight; empty when all are ``gyro_age_s`` old): one late packet makes one reading old, not
    the others."""
    link_latency_s: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    """Per-module round trip of a command, s (median over a recent window; NaN until measured; empty when the
    backend does not measure it)."""
    link_loss: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    """Per-module fraction of recent commands the module did not accept (lost or reordered; on MAVLink, of probes
    unanswered, taken each way; NaN until measured;
    empty when not measured)."""
    module_faults: tuple[str, ...] = ()
    """Per module, why it no longer flies ("" while it does): its firmware stopped flying it since arming
    (disarmed, locked, crashed, restarted, taking another sender's commands; latched for the rest of the flight),
    or it sends no state (while it is silent); empty when the backend cannot tell."""
    rerouted: str = ""
    """How the links stopped being what preflight checked, in flight ("" while they are): re-routed because one
    reached another module than its own, or a module no longer answering the claims that would show it; the flight
    lands."""


def bounded_command(u: np.ndarray, u_max: float) -> np.ndarray:
    """The rotor inputs a backend may apply: NaN/inf stop that rotor, everything clipped to ``[0, u_max]``.

    Every backend applies this at its edge, whatever the caller computed.
    """
    return np.minimum(np.maximum(np.where(np.isfinite(u), u, 0.0), 0.0), u_max)  # per period: no np.clip overhead


def applied_command(u, size: int, armed: bool, u_max: float) -> np.ndarray:
    """What a backend applies for a command: ``size`` rotor inputs (else ValueError), bounded, zero unless armed."""
    u = np.asarray(u, dtype=float)
    if u.shape != (size,):
        raise ValueError(f"expected {size} rotor inputs, got {u.shape}")
    return bounded_command(u, u_max) if armed else np.zeros(size)


def body_rates(module_rotations: np.ndarray, module_gyros: np.ndarray) -> np.ndarray:
    """(n, 3) the modules' gyros, each in its own frame, rotated into the body frame (rad/s): rigidly joined
    modules all measure the body rate (:attr:`Telemetry.gyro` is their mean)."""
    return np.einsum("nij,nj->ni", module_rotations, module_gyros)


@runtime_checkable
class Backend(Protocol):
    def connect(self) -> None: ...
    def preflight(self) -> PreflightReport: ...
    def arm(self) -> None: ...
    def send(self, u: np.ndarray) -> None: ...
    def telemetry(self) -> Telemetry: ...
    def disarm(self) -> None: ...
    def emergency_stop(self) -> None: ...
    def close(self) -> None: ...


@runtime_checkable
class SimulatedBackend(Backend, Protocol):
    """A backend that owns simulated time and knows the true state (PyBullet): what lockstep simulation
    (:class:`~groundstation.runtime.loop.SimClock`), truth logging and fault drills use."""

    link_ok: bool
    """Set False to inject a link loss (telemetry reports it; the flight must stop the motors)."""

    @property
    def time(self) -> float:
        """Simulated time, s."""
        ...

    def advance_to(self, t: float) -> None: ...
    def true_state(self) -> RigidState: ...
    def mocap_samples(self) -> list[PoseMeasurement]:
        """The simulated motion capture's samples delivered since the last call (at its rate, with its noise and
        latency; times: capture, simulated s)."""
        ...


class BackendBase(ABC):
    """What every backend shares: ``armed``, and ``with backend:`` connects and, on the way out, stops the motors
    of an armed backend (an exception inside the block must not leave rotors spinning) and closes its links."""

    _armed: bool = False

    @property
    def armed(self) -> bool:
        return self._armed

    def isolate(self, modules) -> bool:
        """Take the faulty ``modules`` (indices) out of the flight, motors stopped, so the others can land the
        assembly; False where the backend cannot stop single modules (the flight then stops them all)."""
        return False

    def idle_inputs(self) -> np.ndarray:
        """(4n,) rotor inputs an armed module never goes below whatever it is sent (its firmware's idle floor),
        rad^2/s^2; zeros where the firmware has none. Empty before the backend knows its modules."""
        return np.zeros(0)

    def module_gravity(self) -> np.ndarray | None:
        """(n, 3): up (against gravity) in each module's own frame as the module measures it, unit, for the
        preflight's placement check (:mod:`groundstation.runtime.placement`); None where the backend's modules
        report no such thing (a simulator's modules are where the assembly file says)."""
        return None

    @abstractmethod
    def connect(self) -> None: ...

    @abstractmethod
    def emergency_stop(self) -> None: ...

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        if self._armed:
            self.emergency_stop()
        self.close()


LOSS_CONFIDENCE_Z = 2.0
"""The loss read is the lower bound of this many standard deviations (Wilson) on the share lost (PX4's probes, a
Crazyflie's commands): a window is a noisy sample, and its plain share landed flights on healthy 2-5 % links."""


def wilson_lower(k: int, n: int, z: float) -> float:
    """Lower end of the Wilson score interval of ``k`` in ``n`` at ``z`` standard deviations (``k`` taken within
    0..``n``)."""
    k = min(max(k, 0), n)
    if k == 0:
        return 0.0  # exactly (rounding left 3e-18, which a log reads as loss)
    p = k / n
    centre = p + z * z / (2 * n)
    spread = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, (centre - spread) / (1 + z * z / n))
