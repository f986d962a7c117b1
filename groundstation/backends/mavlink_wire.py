"""MAVLink conventions between the ground station and one module running PX4 (<= 1.13) with a pass-through mixer.

PX4 >= 1.14 removed per-actuator offboard control over MAVLink (``SET_ACTUATOR_CONTROL_TARGET``); PX4 <= 1.13,
and firmware that still honours that message, take it in offboard mode. Each module loads
``firmware_params/px4/passthrough_quad.main.mix``, which routes group-0 control q (q = 0..3) straight to main
output q, so the four controls are the module's four rotor commands (see ``firmware_params/README.md``).

* Motor command, ground -> module: ``SET_ACTUATOR_CONTROL_TARGET`` (group 0), ``controls[q] = u_q / u_max`` in
  [0, 1] for the module's rotors q = 1..4, the other four controls 0. The mixer maps [0, 1] onto the full PWM
  range, so commanded PWM = ``pwm_min + controls[q] * (pwm_max - pwm_min)``.
* Applied motors, module -> ground: ``SERVO_OUTPUT_RAW`` (PWM in microseconds), mapped back with the same range.
* Body rate: ``ATTITUDE`` rollspeed/pitchspeed/yawspeed, rad/s, in PX4's body frame FRD (x forward, y right,
  z down); the assembly's module frames are FLU (z up, along the thrust), so y and z change sign.
* Attitude: ``ATTITUDE`` roll/pitch/yaw, rad: ZYX Euler angles of the FRD body frame in PX4's NED world; the
  preflight's placement check takes the direction of gravity in the module frame from roll and pitch
  (:func:`up_in_module`).
* Identity: the autopilot's system id (``MAV_SYS_ID``, unique per vehicle on a shared link; learnt from its
  heartbeat).
* Battery: ``SYS_STATUS.voltage_battery``, mV.
* Arming: ``MAV_CMD_DO_SET_MODE`` to offboard (PX4 accepts it only while setpoints stream), then
  ``MAV_CMD_COMPONENT_ARM_DISARM``; each answered by ``COMMAND_ACK``; ``HEARTBEAT.base_mode`` reports armed.
* Emergency stop: ``MAV_CMD_COMPONENT_ARM_DISARM`` with param2 = 21196 (disarm even in flight), then
  ``MAV_CMD_DO_FLIGHTTERMINATION`` (latches until reboot, like the Crazyflie supervisor's stop).
* Parameters: ``PARAM_REQUEST_READ`` / ``PARAM_SET``, answered by ``PARAM_VALUE``. PX4 encodes integer
  parameters bytewise: the float32 ``param_value`` field carries the integer's bytes, not its value.
"""

from __future__ import annotations

import struct

import numpy as np

PX4_MAIN_MODE_OFFBOARD = 6
"""PX4 custom main mode number of offboard."""
PX4_OFFBOARD_CUSTOM_MODE = PX4_MAIN_MODE_OFFBOARD << 16
"""``HEARTBEAT.custom_mode`` of a PX4 vehicle in offboard (main mode in bits 16-23)."""
FORCE_DISARM = 21196.0
"""``MAV_CMD_COMPONENT_ARM_DISARM`` param2 that disarms even in flight."""
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190
"""MAV_COMP_ID_MISSIONPLANNER, the usual ground-station component."""
ACTUATOR_GROUP = 0
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])
"""Maps a vector from PX4's FRD body frame to the module's FLU frame (its own inverse)."""
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""Maps a vector from the ground station's ENU world (z up) to PX4's NED world (its own inverse)."""


def px4_attitude(rotation: np.ndarray) -> np.ndarray:
    """The FRD-in-NED rotation PX4 reports for a module whose FLU frame has ``rotation`` in the ENU world."""
    return ENU_TO_NED @ np.asarray(rotation, float) @ FRD_TO_FLU


def up_in_module(roll: float, pitch: float) -> np.ndarray:
    """Up (against gravity) in the module's FLU frame from PX4's ``ATTITUDE`` roll and pitch, rad."""
    down_frd = np.array([-np.sin(pitch), np.sin(roll) * np.cos(pitch), np.cos(roll) * np.cos(pitch)])
    return FRD_TO_FLU @ -down_frd


def to_controls(u: np.ndarray, u_max: float) -> list[float]:
    """Four rotor inputs (rad^2/s^2) -> the eight group-0 controls: u / u_max in [0, 1], then four zeros."""
    return [min(max(float(v) / u_max, 0.0), 1.0) for v in u] + [0.0] * 4


def from_controls(controls, u_max: float) -> np.ndarray:
    """The first four group-0 controls -> rotor inputs, rad^2/s^2 (clamped to [0, u_max])."""
    return np.clip(np.asarray(controls[:4], float), 0.0, 1.0) * u_max


def to_pwm(u: np.ndarray, u_max: float, pwm_min: int, pwm_max: int) -> list[int]:
    """Rotor inputs -> the PWM the pass-through mixer outputs, us."""
    return [int(round(pwm_min + c * (pwm_max - pwm_min))) for c in to_controls(u, u_max)[:4]]


def from_pwm(pwm, u_max: float, pwm_min: int, pwm_max: int) -> np.ndarray:
    """PWM outputs (us) -> rotor inputs, rad^2/s^2; at or below ``pwm_min`` (or a disarmed 0) is no thrust."""
    return np.clip((np.asarray(pwm, float) - pwm_min) / (pwm_max - pwm_min), 0.0, 1.0) * u_max


PARAM_INT_FORMATS = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}
"""MAV_PARAM_TYPE_UINT8 .. INT32 -> struct format; MAV_PARAM_TYPE_REAL32 (9) travels as itself."""
PARAM_CTYPES = {1: "uint8_t", 2: "int8_t", 3: "uint16_t", 4: "int16_t", 5: "uint32_t", 6: "int32_t", 9: "float"}
"""MAV_PARAM_TYPE -> the C type it holds (as cflib names them)."""


def param_to_wire(value: float, param_type: int) -> float:
    """A parameter value as the float32 ``param_value`` field carries it (PX4's bytewise integer encoding)."""
    fmt = PARAM_INT_FORMATS.get(param_type)
    if fmt is None:
        return float(value)
    raw = struct.pack(fmt, int(round(value))).ljust(4, b"\0")
    return struct.unpack("<f", raw)[0]


def param_from_wire(field: float, param_type: int) -> float:
    """The parameter value in a ``param_value`` field (inverse of :func:`param_to_wire`)."""
    fmt = PARAM_INT_FORMATS.get(param_type)
    if fmt is None:
        return float(field)
    raw = struct.pack("<f", field)
    return float(struct.unpack(fmt, raw[:struct.calcsize(fmt)])[0])
