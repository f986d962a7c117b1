"""JSON Schemas of the flight log's JSON channels: Foxglove offers their fields to plot, and replay relies on them.

Every field with a unit names it (``position_m``, ``command_frac_umax``); vectors are world frame unless said
otherwise. Rotations in records are written as an ``orientation`` quaternion (x, y, z, w) and ``rpy_deg`` (ZYX
roll, pitch, yaw in degrees): the flight process hands the writer rotation matrices and the writer converts them.

The schemas stay inside what Foxglove's JSON-schema parser (Foxglove and Lichtblick alike) takes, or it drops the
whole channel: objects with ``properties``; fields of type boolean, string, number, integer or object; arrays of
one of those, never arrays of arrays (a value per module and rotor is an array of per-module objects:
``/control.modules[0].command_frac_umax[2]``, one index per field as Foxglove's message paths allow); and no
nullable types (``"type": ["number", "null"]`` is refused too). So JSON's lack of NaN and infinity is met by
absence: the writer leaves out a member whose value is not finite or is an array holding a value that is not
(:func:`groundstation.flightlog.mcap_log.encode_json`), and no member that can be so is required. A value per
module that is often unknown (a link's round trip before it is measured) is a member of the module's object for
that reason, where an array would have to drop the whole field.
"""

from __future__ import annotations

import json


def _vec(n: int, description: str) -> dict:
    return {"type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n,
            "description": description}


def _num(description: str) -> dict:
    return {"type": "number", "description": description}


def _attitude(description: str) -> dict:
    return {"type": "object", "description": description,
            "properties": {"orientation": _vec(4, "quaternion x, y, z, w (body to world)"),
                           "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg")}}


def _obj(description: str, properties: dict, required: tuple[str, ...] = ()) -> dict:
    out = {"type": "object", "description": description, "properties": properties}
    if required:
        out["required"] = list(required)
    return out


def _modules(description: str, properties: dict) -> dict:
    """One object per module, in module order."""
    return {"type": "array", "description": description, "items": _obj("one module", properties)}


_STATE = _obj("the state the controller used (the estimator's, at the period's time; body rate: the gyros' less "
              "their estimated bias)", {
    "position_m": _vec(3, "m"), "velocity_mps": _vec(3, "m/s"),
    "orientation": _vec(4, "quaternion x, y, z, w"), "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg"),
    "omega_radps": _vec(3, "body rate, body frame, rad/s")})

_MOCAP_COUNTS = {
    "rejected": {"type": "integer", "description": "jumps, stale or out-of-order samples"},
    "malformed": {"type": "integer", "description": "samples that did not decode"},
    "missed": {"type": "integer", "description": "gaps in the publisher's sequence"}}
_ESTIMATOR_COUNTS = {
    "rejected": {"type": "integer", "description": "poses the innovation gates rejected so far"},
    "late": {"type": "integer", "description": "poses captured before the oldest estimate kept, dropped unused so "
                                              "far"}}

CONTROL = _obj("one control period", {
    "t_s": _num("flight time since the first period, s"),
    "phase": {"type": "string", "description": "takeoff, settle, track, hold, landing, done, emergency"},
    "state": _STATE,
    "truth": _obj("simulated flights only: the physics state", {
        "position_m": _vec(3, "m"), "orientation": _vec(4, "quaternion x, y, z, w"),
        "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg")}),
    "setpoint": _obj("the reference", {
        "position_m": _vec(3, "m"), "velocity_mps": _vec(3, "m/s"), "acceleration_mps2": _vec(3, "m/s^2"),
        "orientation": _vec(4, "quaternion x, y, z, w"), "rpy_deg": _vec(3, "ZYX roll, pitch, yaw, deg"),
        "omega_radps": _vec(3, "desired body rate, body frame, rad/s")}),
    "position_error_m": _vec(3, "position flown less the reference's (flown: the physics truth in simulation, the "
                                "estimate otherwise; what the tracking figures measure), m"),
    "attitude_target": _attitude("the attitude the controller aimed at (R_d: the setpoint's roll and yaw, pitch "
                                 "from the translation for under-actuated assemblies)"),
    "roll_target_deg": _num("deg"),
    "yaw_target_deg": _num("deg"),
    "wrench": _obj("desired wrench, body frame", {"force_n": _vec(3, "N"), "torque_nm": _vec(3, "N m")}),
    "modules": _modules("per module", {
        "command_frac_umax": _vec(4, "rotor commands q = 1..4, fraction of u_max (zero in motors-off records)"),
        "applied_frac_umax": _vec(4, "motors-off records only: the rotor inputs the backend reported, fraction "
                                     "of u_max")}),
    "command_max_frac_umax": _num("the largest rotor command of the period, fraction of u_max (1: a rotor "
                                  "saturated at its upper bound)"),
    "command_min_frac_umax": _num("the smallest, fraction of u_max (0: a rotor at its lower bound)"),
    "motors_off": {"type": "boolean", "description": "the motors were commanded off in this period"},
    "mocap_age_s": _num("time since the capture of the newest pose fused, s (absent before the first)"),
    "mocap": _obj("the pose subscriber's counters so far (as /mocap/stats has them once a second)", _MOCAP_COUNTS),
    "estimate": _obj("the estimator's uncertainty and health", {
        "position_sigma_m": _num("horizontal position std per axis, m"),
        "height_sigma_m": _num("height std, m"),
        "velocity_sigma_mps": _num("velocity std per axis, m/s"),
        "attitude_sigma_deg": _num("attitude std per axis, deg"),
        "gyro_bias_radps": _vec(3, "estimated gyro bias, body frame, rad/s"),
        "disturbance_mps2": _vec(3, "acceleration the model misses, world frame, m/s^2"),
        "innovation_position_m": _vec(3, "newest pose's position minus the estimate at its capture time, m"),
        "innovation_attitude_deg": _vec(3, "newest pose's attitude relative to the estimate, body rotation "
                                           "vector, deg"),
        "fused": {"type": "integer", "description": "poses fused so far"}, **_ESTIMATOR_COUNTS}),
    "loop": _obj("timing of the previous period", {
        "start_error_s": _num("s"), "compute_s": _num("s"), "overruns": {"type": "integer"}}),
}, required=("t_s", "phase", "modules"))

FLIGHT_START = _obj("the counters as preflight passed, before arming: where the counts of every period's record "
                    "start from (a replayed window from the first period has its own)", {
    "mocap": _obj("the pose subscriber's counters", _MOCAP_COUNTS),
    "estimate": _obj("the estimator's counters", _ESTIMATOR_COUNTS)}, required=("mocap", "estimate"))

TELEMETRY = _obj("what the modules report, a tenth of the control rate", {
    "t_s": _num("flight time, s"),
    "link_ok": {"type": "boolean"},
    "gyro_radps": _vec(3, "body rate from the modules' IMUs, body frame, rad/s (absent when not streamed)"),
    "modules": _modules("per module (each member absent when the backend does not report it, or not yet)", {
        "rotor_speed_sq_rad2_s2": _vec(4, "rotor inputs applied q = 1..4: rotor speed squared, rad^2/s^2"),
        "battery_v": _num("battery, V"),
        "link_latency_s": _num("round trip of the module's link (a command's echo on Crazyflie, a TIMESYNC answer "
                               "on MAVLink), s"),
        "link_loss_frac": _num("fraction of recent commands the module did not accept")}),
}, required=("t_s", "link_ok"))

MOCAP_STATS = _obj("the pose subscriber's counters since the start, about once a second", {
    "received": {"type": "integer", "description": "well-formed samples"},
    "accepted": {"type": "integer", "description": "samples the estimate used"},
    "rejected": {"type": "integer", "description": "jumps, stale or out-of-order samples"},
    "malformed": {"type": "integer", "description": "samples that did not decode"},
    "missed": {"type": "integer", "description": "gaps in the publisher's sequence"},
    "foreign": {"type": "integer", "description": "samples from a publisher other than the body's source"},
    "unauthenticated": {"type": "integer", "description": "samples without a valid MAC (mocap.key_file set)"},
    "bad_stamps": {"type": "integer", "description": "samples whose stamp disagrees with their arrival time"},
    "unechoed": {"type": "integer", "description": "of the bad stamps, samples echoing none of this ground "
                                                   "station's challenges of the last second (mocap.key_file set)"},
    "conflicts": {"type": "integer", "description": "samples out of sequence under the source's id (a copy)"},
    "resyncs": {"type": "integer", "description": "times the estimate followed a new consistent track"},
    "duplicates": {"type": "integer", "description": "exact copies of the newest sample, dropped"},
    "handovers": {"type": "integer", "description": "times a new authenticated publisher became the source after "
                                                    "the old one's silence (a restarted bridge; mocap.key_file set)"},
    "rate_hz": _num("accepted samples a second over the last interval (absent in the first record: no interval "
                    "yet)"),
}, required=("received", "rejected", "malformed"))

LOOP_TIMING = _obj("the control loop over the whole flight", {
    "periods": {"type": "integer"}, "rate_hz": _num("configured rate, Hz"), "overruns": {"type": "integer"},
    "realtime": {"type": "boolean"},
    "start_error_ms_p50": _num("ms"), "start_error_ms_p99": _num("ms"), "start_error_ms_max": _num("ms"),
    "compute_ms_p50": _num("ms"), "compute_ms_p99": _num("ms"),
    "overrun_starts": {"type": "array", "items": {"type": "number"},
                       "description": "when each late period was due, s (the loop's clock)"}})

FLIGHT_SUMMARY = _obj("the flight's figures, as groundstation fly --json prints them (NaN figures, of phases never "
                      "reached, absent)", {
    "phase": {"type": "string"}, "reason": {"type": "string"},
    "degraded": {"type": "array", "items": {"type": "string"},
                 "description": "what went beyond the flight's bounds (empty: within them)"},
    "pos_rmse_m": _num("tracking: RMS of the position error's norm, m"),
    "max_pos_error_m": _num("tracking: largest position error norm, m"),
    "pos_rmse_xyz_m": _vec(3, "RMS per world axis, m"), "max_pos_error_xyz_m": _vec(3, "per world axis, m"),
    "max_orientation_error_deg": _num("deg"), "orientation_error_p50_deg": _num("deg"),
    "orientation_error_p95_deg": _num("deg"), "max_roll_error_deg": _num("deg"), "max_yaw_error_deg": _num("deg"),
    "max_motor_fraction": _num("the largest rotor command, fraction of u_max"),
    "saturation_fraction": {"type": "array", "items": {"type": "number"},
                            "description": "per module: share of airborne periods with a rotor at a bound"},
    "motor_change_rms": _num("RMS change of a rotor command from one tracking period to the next, fraction of "
                             "u_max"),
    "motor_change_max": _num("the largest such change, fraction of u_max"),
    "mocap_age_p99_ms": _num("ms"), "loop_period_error_p50_ms": _num("ms"), "loop_period_error_p99_ms": _num("ms"),
    "compute_p99_ms": _num("ms"), "periods": {"type": "integer"}, "simulated_s": _num("flight time flown, s"),
    "realtime_factor": _num("flight time per wall-clock second"), "planned_s": _num("the plan's duration, s"),
    "crashed": {"type": "boolean", "description": "ended in an emergency stop"},
    "stalls": {"type": "integer", "description": "loop stalls logged"}})

SCHEMAS = {"/control": CONTROL, "/backend/telemetry": TELEMETRY, "/mocap/stats": MOCAP_STATS,
           "/loop/timing": LOOP_TIMING, "/flight/start": FLIGHT_START, "/flight/summary": FLIGHT_SUMMARY}


def schema_of(topic: str) -> bytes:
    """The JSON Schema of a JSON channel: an object of no declared fields for a topic without one (Foxglove's
    parser needs ``properties`` even then, or it drops the channel)."""
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": topic,
                       **SCHEMAS.get(topic, {"type": "object", "properties": {}})}).encode()
