"""JSON Schemas of the flight log's JSON channels: Foxglove offers their fields to plot, and replay relies on them.

Units are in the field names or descriptions; vectors are world frame unless said otherwise. Rotations in
records are written as an ``orientation`` quaternion (x, y, z, w) and ``rpy_deg`` (ZYX roll, pitch, yaw in
degrees): the flight process hands the writer rotation matrices and the writer converts them.
"""

from __future__ import annotations

import json


def _vec(n: int, description: str) -> dict:
    return {"type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n,
            "description": description}


def _per_module(description: str, inner: dict | None = None) -> dict:
    return {"type": "array", "items": inner or {"type": "number"}, "description": description}


def _attitude(description: str) -> dict:
    return {"type": "object", "description": description,
            "properties": {"orientation": _vec(4, "quaternion x, y, z, w (body to world)"),
                           "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg")}}


def _obj(description: str, properties: dict, required: tuple[str, ...] = ()) -> dict:
    out = {"type": "object", "description": description, "properties": properties}
    if required:
        out["required"] = list(required)
    return out


_STATE = _obj("the state the controller used (the estimator's, at the period's time; body rate: the gyros' less "
              "their estimated bias)", {
    "position": _vec(3, "m"), "velocity": _vec(3, "m/s"),
    "orientation": _vec(4, "quaternion x, y, z, w"), "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg"),
    "omega": _vec(3, "body rate, body frame, rad/s")})

CONTROL = _obj("one control period", {
    "t": {"type": "number", "description": "flight time since the first period, s"},
    "phase": {"type": "string", "description": "takeoff, settle, track, hold, landing, done, emergency"},
    "state": _STATE,
    "truth": _obj("simulated flights only: the physics state", {
        "position": _vec(3, "m"), "orientation": _vec(4, "quaternion x, y, z, w"),
        "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg")}),
    "setpoint": _obj("the reference", {
        "position": _vec(3, "m"), "velocity": _vec(3, "m/s"), "acceleration": _vec(3, "m/s^2"),
        "orientation": _vec(4, "quaternion x, y, z, w"), "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg"),
        "omega": _vec(3, "desired body rate, body frame, rad/s")}),
    "attitude_target": _attitude("the attitude the controller aimed at (R_d: the setpoint's roll and yaw, pitch "
                                 "from the translation for under-actuated assemblies)"),
    "roll_target_deg": {"type": "number", "description": "deg"},
    "yaw_target_deg": {"type": "number", "description": "deg"},
    "wrench": _obj("desired wrench, body frame", {"force": _vec(3, "N"), "torque": _vec(3, "N m")}),
    "motors": _per_module("rotor commands per module (q = 1..4), fraction of u_max",
                          _vec(4, "fraction of u_max")),
    "applied": _per_module("motors-off records: rotor inputs the backend reported, fraction of u_max",
                           _vec(4, "fraction of u_max")),
    "motors_off": {"type": "boolean", "description": "the motors were commanded off in this period"},
    "mocap_age_s": {"type": "number", "description": "time since the capture of the newest pose fused, s"},
    "estimate": _obj("the estimator's uncertainty and health", {
        "position_sigma_m": {"type": "number", "description": "position std per axis, m"},
        "velocity_sigma_mps": {"type": "number", "description": "velocity std per axis, m/s"},
        "attitude_sigma_deg": {"type": "number", "description": "attitude std per axis, deg"},
        "gyro_bias_radps": _vec(3, "estimated gyro bias, body frame, rad/s"),
        "disturbance_mps2": _vec(3, "acceleration the model misses, world frame, m/s^2"),
        "innovation_position_m": _vec(3, "newest pose's position minus the estimate at its capture time, m"),
        "innovation_attitude_deg": _vec(3, "newest pose's attitude relative to the estimate, body rotation "
                                           "vector, deg"),
        "fused": {"type": "integer", "description": "poses fused so far"},
        "rejected": {"type": "integer", "description": "poses the innovation gates rejected so far"},
        "late": {"type": "integer", "description": "poses captured before the oldest estimate kept, dropped unused "
                                                  "so far"}}),
    "loop": _obj("timing of the previous period", {
        "start_error_s": {"type": "number"}, "compute_s": {"type": "number"}, "overruns": {"type": "integer"}}),
}, required=("t", "phase", "motors"))

TELEMETRY = _obj("what the modules report, a tenth of the control rate", {
    "t": {"type": "number", "description": "flight time, s"},
    "link_ok": {"type": "boolean"},
    "motors": {"type": "array", "items": {"type": "number"}, "description": "rotor inputs applied, rad^2/s^2"},
    "battery_v": _per_module("battery per module, V"),
    "gyro": _vec(3, "body rate from the modules' IMUs, rad/s"),
    "link_latency_s": _per_module("command round trip per module, s (NaN: not measured)"),
    "link_loss": _per_module("fraction of commands a module did not accept"),
}, required=("t", "link_ok"))

MOCAP_STATS = _obj("the pose subscriber's counters since the start, about once a second", {
    "received": {"type": "integer", "description": "well-formed samples"},
    "accepted": {"type": "integer", "description": "samples the estimate used"},
    "rejected": {"type": "integer", "description": "jumps, stale or out-of-order samples"},
    "malformed": {"type": "integer", "description": "samples that did not decode"},
    "missed": {"type": "integer", "description": "gaps in the publisher's sequence"},
    "foreign": {"type": "integer", "description": "samples from a publisher other than the body's source"},
    "unauthenticated": {"type": "integer", "description": "samples without a valid MAC (mocap.key_file set)"},
    "bad_stamps": {"type": "integer", "description": "samples whose stamp disagrees with their arrival time"},
    "conflicts": {"type": "integer", "description": "samples out of sequence under the source's id (a copy)"},
    "resyncs": {"type": "integer", "description": "times the estimate followed a new consistent track"},
    "rate_hz": {"type": "number", "description": "accepted samples a second over the last interval"},
}, required=("received", "rejected", "malformed"))

LOOP_TIMING = _obj("the control loop over the whole flight", {
    "periods": {"type": "integer"}, "rate_hz": {"type": "number"}, "overruns": {"type": "integer"},
    "realtime": {"type": "boolean"},
    "start_error_ms_p50": {"type": "number"}, "start_error_ms_p99": {"type": "number"},
    "start_error_ms_max": {"type": "number"}, "compute_ms_p50": {"type": "number"},
    "compute_ms_p99": {"type": "number"},
    "overrun_starts": {"type": "array", "items": {"type": "number"}}})

FLIGHT_SUMMARY = _obj("the flight's figures, as groundstation fly --json prints them", {
    "phase": {"type": "string"}, "reason": {"type": "string"},
    "degraded": {"type": "array", "items": {"type": "string"},
                 "description": "what went beyond the flight's bounds (empty: within them)"},
    "pos_rmse_m": {"type": "number"}, "max_pos_error_m": {"type": "number"},
    "max_orientation_error_deg": {"type": "number"}, "max_roll_error_deg": {"type": "number"},
    "max_motor_fraction": {"type": "number"}})

SCHEMAS = {"/control": CONTROL, "/backend/telemetry": TELEMETRY, "/mocap/stats": MOCAP_STATS,
           "/loop/timing": LOOP_TIMING, "/flight/summary": FLIGHT_SUMMARY}


def schema_of(topic: str) -> bytes:
    """The JSON Schema of a JSON channel (a bare object for a topic without one)."""
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": topic,
                       **SCHEMAS.get(topic, {"type": "object"})}).encode()
