"""Flight config bounds: every number of the config has one, checked before anything opens (``prepare``)."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from groundstation import config
from groundstation.assembly.assembly_file import load_assembly
from groundstation.backends.section import CrazyflieSection, MavlinkSection, SimSection
from groundstation.errors import ConfigError
from groundstation.runtime.flight_config import (
    FlightConfig,
    axis_coupling,
    bound_issues,
    load_flight_config,
    loop_rate_needed,
)
from groundstation.runtime.fly import prepare

ROOT = Path(__file__).resolve().parents[2]
TOY = ROOT / "configs/assemblies/toy_v2.json"
BACKENDS = {"sim": SimSection(),
            "crazyflie": CrazyflieSection(modules=("udp://127.0.0.1:19850", "udp://127.0.0.1:19851")),
            "mavlink": MavlinkSection(modules=("udpout:127.0.0.1:14560", "udpout:127.0.0.1:14561"))}
"""Every backend kind with every key (defaults)."""


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)  # ints, floats: 1e+300, nan, inf, -inf are TOML


def write_config(path: Path, data: dict) -> Path:
    """``data`` (scalars at the top, then one table per section) as a TOML file."""
    top = [f"{k} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    tables = [f"[{k}]\n" + "\n".join(f"{kk} = {_toml_value(vv)}" for kk, vv in v.items() if vv is not None)
              for k, v in data.items() if isinstance(v, dict)]
    path.write_text("\n".join(top) + "\n\n" + "\n\n".join(tables) + "\n")
    return path


def full_config(kind: str) -> dict:
    """Every key of a flight config with its default, for a backend ``kind`` (TLS and access control left out)."""
    data = dataclasses.asdict(FlightConfig(assembly=str(TOY), backend=BACKENDS[kind]))
    data["mocap"] = {k: v for k, v in data["mocap"].items() if v is not None}
    return data


def numeric_keys(data: dict, prefix: str = ""):
    """``(key path, value)`` of every number (tuple elements as ``key.i``)."""
    for k, v in data.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            yield from numeric_keys(v, key + ".")
        elif isinstance(v, list | tuple):
            yield from ((f"{key}.{i}", x) for i, x in enumerate(v) if isinstance(x, int | float))
        elif isinstance(v, int | float) and not isinstance(v, bool):
            yield key, v


def with_value(data: dict, key: str, value) -> dict:
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    *sections, last = key.split(".")
    node = out
    if last.isdigit():  # a tuple element
        *sections, name = sections
        for s in sections:
            node = node[s]
        node[name] = [value if i == int(last) else x for i, x in enumerate(node[name])]
        return out
    for s in sections:
        node = node[s]
    node[last] = value
    return out


def test_the_defaults_are_within_bounds(tmp_path):  # the shipped configs: tests/runtime/test_fly.py
    for kind in BACKENDS:
        cfg, _ = load_flight_config(write_config(tmp_path / f"{kind}.toml", full_config(kind)))
        assert cfg.backend.kind == kind


ABSURD = [1e300, -1e300, math.nan, math.inf, -math.inf]


@pytest.mark.parametrize("kind", sorted(BACKENDS))
def test_every_numeric_key_has_a_bound(tmp_path, kind):
    """1e300, -1e300 and the non-finite values in every number of the config: each one is refused by ``prepare``
    (config, assembly, plan; before anything opens), naming the key."""
    data = full_config(kind)
    keys = [k for k, _ in numeric_keys(data) if kind == "sim" or k.startswith("backend.")]
    assert len(keys) >= (30 if kind == "sim" else 3), keys  # the walk found the keys
    log = tmp_path / "x.mcap"
    for key in keys:
        for value in ABSURD:
            if isinstance(dict(numeric_keys(data))[key], int) and math.isfinite(value):
                value = int(math.copysign(10**12, value))  # an int key: an absurd int
            path = write_config(tmp_path / "f.toml", with_value(data, key, value))
            with pytest.raises(ConfigError) as exc:
                prepare(path, log_path=log)
            leaf = next(part for part in reversed(key.split(".")) if not part.isdigit())
            named = exc.value.key == key or key.startswith(f"{exc.value.key}.") or leaf in str(exc.value)
            assert named, (key, value, str(exc.value))
            assert str(path) in str(exc.value) and "\n" not in str(exc.value)
    assert not log.exists()


def _closed_loop_radius(w_t: float, zeta: float) -> float:
    """Spectral radius of a PD loop on a double integrator (natural frequency x period ``w_t``, damping ``zeta``)
    sampled with a zero-order hold and one period of delay: the exact discrete loop, an oracle independent of the
    phase-margin rule."""
    a = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [-(w_t**2), -2 * zeta * w_t, 0.0]])  # x, v, u held (T = 1)
    return float(max(abs(np.linalg.eigvals(a))))


@pytest.mark.parametrize("zeta", [0.05, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0, 1.5, 2.0, 5.0, 10.0, 20.0])
def test_the_loop_rule_keeps_half_the_bandwidth_at_which_the_sampled_loop_goes_unstable(zeta):
    rate = loop_rate_needed(4.0, zeta)
    w_t = 2 * math.pi * 4.0 / rate
    assert _closed_loop_radius(w_t, zeta) < 1
    assert _closed_loop_radius(1.85 * w_t, zeta) < 1  # margin: at least 1.85 times the bandwidth ...
    assert _closed_loop_radius(2.05 * w_t, zeta) > 1  # ... and no more than 2.05 (the rule is not loose)
    assert loop_rate_needed(8.0, zeta) == pytest.approx(2 * rate)  # proportional to the bandwidth


def test_the_loop_rule_for_the_default_gains():
    assert loop_rate_needed(4.0, 0.9) == pytest.approx(110.3, abs=0.1)  # attitude, 250 Hz realises it
    assert loop_rate_needed(0.8, 1.0) == pytest.approx(23.3, abs=0.1)  # position


def test_axis_coupling_of_the_inertia():
    assert axis_coupling(np.diag([1.0, 2.0, 3.0])) == pytest.approx([1.0, 1.0, 1.0])
    fig1, _ = load_assembly(ROOT / "configs/assemblies/paper_fig1_n12.json")
    mus = axis_coupling(fig1.inertia)
    assert mus[0] < 0.9 and mus[-1] > 1.2  # off-diagonal inertia: one attitude mode 1.11 x faster (sqrt 1.225)


def _issue(cfg: FlightConfig, inertia, **changes) -> list:
    for section, values in changes.items():
        cfg = dataclasses.replace(cfg, **{section: dataclasses.replace(getattr(cfg, section), **values)}) \
            if isinstance(values, dict) else dataclasses.replace(cfg, **{section: values})
    return list(bound_issues(cfg, inertia))


def test_the_attitude_bound_depends_on_the_assembly():
    cfg = FlightConfig(assembly="x")
    toy, _ = load_assembly(TOY)
    fig1, _ = load_assembly(ROOT / "configs/assemblies/paper_fig1_n12.json")
    gains = {"attitude_hz": 8.0}  # 250 Hz realises 9.06 Hz on principal axes, less with coupled ones
    toy_issues = [k for k, _ in _issue(cfg, toy.inertia, gains=gains)]
    fig1_issues = [k for k, _ in _issue(cfg, fig1.inertia, gains=gains)]
    assert "gains.attitude_hz" not in toy_issues and "gains.attitude_hz" in fig1_issues


def test_the_sim_loop_runs_at_the_slower_of_control_and_physics():
    cfg = FlightConfig(assembly="x")
    toy, _ = load_assembly(TOY)
    slow = _issue(cfg, toy.inertia, backend=dataclasses.replace(cfg.backend, physics_hz=100.0))
    assert slow[0][0] == "gains.attitude_hz" and "(backend.physics_hz)" in slow[0][1]
    assert _issue(cfg, toy.inertia, rate_hz=100.0)[0][1].endswith("half the phase margin)")


@pytest.mark.parametrize("changes, key", [
    ({"mocap": {"latency_s": 0.3}}, "mocap.latency_s"),
    ({"mocap": {"latency_s": 0.24, "rate_hz": 50.0}}, "mocap.latency_s"),  # 0.24 s + 0.02 s sample interval
    ({"trajectory": {"roll_deg": -75.0}}, "trajectory.roll_deg"),
    ({"trajectory": {"roll_deg": 45.0}}, "trajectory.roll_deg"),  # with the controller's 30 deg lean: 75 deg
    ({"failsafe": {"max_tilt_deg": 30.0}}, "failsafe.max_tilt_deg"),  # not above the controller's lean (30 deg)
    ({"failsafe": {"max_stall_s": 0.005}}, "failsafe.max_stall_s"),  # two periods at 250 Hz: 8 ms
    ({"failsafe": {"max_link_latency_s": 0.06}}, "failsafe.max_link_latency_s"),  # not below the stop latency
    ({"failsafe": {"max_tracking_error_m": 10.6}}, "failsafe.max_tracking_error_m"),  # the fence: 10.57 m across
    ({"gains": {"position_hz": 15.0}}, "gains.position_hz"),  # 250 Hz realises 8.24 Hz at zeta 1
    ({"gains": {"attitude_zeta": 1e6}}, "gains.attitude_hz"),
    ({"backend": {"motor_time_constant": 0.05}}, "backend.motor_time_constant"),  # attitude loop: 0.0398 s
    ({"backend": {"physics_hz": 5000.0}}, "backend.physics_hz"),
])
def test_cross_key_bounds(changes, key):
    toy, _ = load_assembly(TOY)
    issues = _issue(FlightConfig(assembly="x"), toy.inertia, **changes)
    assert [k for k, _ in issues] == [key], issues


@pytest.mark.parametrize("key, value", [("position_noise", 0.051), ("attitude_noise_deg", 5.1)])
def test_mocap_noise_beyond_any_mocap_is_refused(key, value):
    """The estimator's gates scale with the noise it is told, so no noise is inconsistent with them; a noise no
    mocap has (5 cm, 5 deg) is a typo."""
    with pytest.raises(ConfigError, match=rf"mocap.{key}: .*less than or equal to"):
        config.validate(FlightConfig, {"assembly": "x", "mocap": {key: value}})


@pytest.mark.parametrize("value, bound", [(0.1, "greater than or equal to 0.2"), (2.5, "less than or equal to 2")])
def test_a_preflight_watch_too_short_to_see_a_second_publisher_or_beyond_the_wait_is_refused(value, bound):
    with pytest.raises(ConfigError, match=rf"mocap.preflight_watch_s: .*{bound}"):
        config.validate(FlightConfig, {"assembly": "x", "mocap": {"preflight_watch_s": value}})


@pytest.mark.parametrize("value, bound", [(-0.001, "greater than or equal to 0"),
                                          (0.051, "less than or equal to 0.05")])
def test_a_clock_drift_that_would_let_a_delay_pass_as_drift_is_refused(value, bound):
    """More than the 50 ms a stamp may disagree with its arrival would let a man in the middle add that much delay,
    grown slowly, with the poses taken for fresh."""
    with pytest.raises(ConfigError, match=rf"mocap.clock_drift_s: .*{bound}"):
        config.validate(FlightConfig, {"assembly": "x", "mocap": {"clock_drift_s": value}})


def test_cross_key_bounds_just_inside():
    toy, _ = load_assembly(TOY)
    assert _issue(FlightConfig(assembly="x"), toy.inertia, mocap={"latency_s": 0.23}, trajectory={"roll_deg": 44.9},
                  failsafe={"max_stall_s": 0.009, "max_tracking_error_m": 10.5},
                  backend={"motor_time_constant": 0.039}) == []


def test_an_assembly_that_is_not_text(tmp_path):
    cfg = write_config(tmp_path / "f.toml", {**full_config("sim"), "assembly": "/dev/zero"})
    with pytest.raises(ConfigError, match=r"f\.toml: assembly: /dev/zero: not a text file"):
        load_flight_config(cfg)


def test_an_access_control_file_that_is_not_text(tmp_path):
    from groundstation.runtime.flight_config import MocapSection, mocap_security

    (tmp_path / "acl.json5").write_bytes(b"\x00\x01\x02")
    with pytest.raises(ConfigError, match=r"^flight.toml: mocap.access_control: .*acl.json5: not a text file"):
        mocap_security(MocapSection(access_control="acl.json5"), tmp_path, "flight.toml")


LOWER_BOUND_EXEMPT = {
    "trajectory.size": "a figure-8 or circle of no size is a hover",
    "trajectory.roll_deg": "any roll the assembly hovers at (bounded by the tilt failsafe and the hover)",
    "trajectory.settle_s": "0: no settling (allowed; the attitude target steps to the trajectory's)",
    "trajectory.landing_s": "a shorter landing is stretched to its height over 0.8 m/s",
}
"""Failsafe and trajectory numbers that may be as small as a positive number gets (geofence coordinates are positions,
not bounds of a size: any is one; those that cannot be flown are refused with the plan)."""


@pytest.mark.parametrize("kind", ["sim", "crazyflie"])
def test_every_failsafe_and_trajectory_key_has_a_lower_bound(tmp_path, kind):
    """1e-12 in each: before, failsafe.max_tilt_deg armed and stopped the motors at once (an emergency stop latches
    real Crazyflie modules), max_disturbance_mps2 stopped them 0.1 s after arming, max_tracking_error_m landed as it
    took off, blind_descent_mps (and the uncertainty bounds) stopped them in the air on a mocap loss."""
    data = full_config(kind)
    keys = [k for k, _ in numeric_keys(data) if k.startswith(("failsafe.", "trajectory."))
            and k not in LOWER_BOUND_EXEMPT and not k.startswith("failsafe.geofence_")]
    assert len(keys) >= 14, keys
    log = tmp_path / "x.mcap"
    for key in keys:
        path = write_config(tmp_path / "f.toml", with_value(data, key, 1e-12))
        with pytest.raises(ConfigError) as exc:
            prepare(path, log_path=log)
        named = exc.value.key == key or key.startswith(f"{exc.value.key}.") or key.split(".")[-1] in str(exc.value)
        assert named and str(path) in str(exc.value) and "\n" not in str(exc.value), (key, str(exc.value))
    assert not log.exists()


def test_the_tilt_failsafe_is_one_that_acts(tmp_path):
    """180 deg never acts (the rotors push the assembly down beyond 90 deg)."""
    path = write_config(tmp_path / "f.toml", with_value(full_config("sim"), "failsafe.max_tilt_deg", 180.0))
    with pytest.raises(ConfigError, match=r"failsafe\.max_tilt_deg: Input should be less than or equal to 90"):
        load_flight_config(path)


@pytest.mark.parametrize("roll, hovers", [(-8.9, True), (8.9, True), (-20.0, False), (40.0, False)])
def test_a_roll_target_the_assembly_cannot_hover_at_names_the_file_and_the_key(tmp_path, roll, hovers):
    """The toy V hovers at roll targets within +-9 deg; at 59 deg (tilt failsafe 90) the refusal named neither the
    file nor the key (a preflight error: "the assembly cannot hover: ...")."""
    data = with_value(full_config("sim"), "failsafe.max_tilt_deg", 90.0)
    path = write_config(tmp_path / "f.toml", with_value(data, "trajectory.roll_deg", roll))
    if hovers:
        load_flight_config(path)
        return
    with pytest.raises(ConfigError) as exc:
        load_flight_config(path)
    assert str(exc.value).startswith(f"{path}: trajectory.roll_deg: {roll:g} deg: the assembly cannot hover")
    assert str(exc.value).endswith("it hovers at roll targets from -9.0 to 9.0 deg")


def test_an_assembly_that_cannot_hover_level_is_named_as_the_assembly():
    from groundstation.assembly.assembly import Assembly
    from groundstation.assembly.module import ModuleParams
    from groundstation.assembly.topology import Topology
    from groundstation.control.model import ControlModel

    weak = Assembly(Topology.from_code("oE"), ModuleParams(u_max=1.0e6), np.zeros(3))  # 1.5 N each for 2.35 N
    issues = list(bound_issues(FlightConfig(assembly="x"), weak.inertia, ControlModel.from_assembly(weak)))
    assert [k for k, _ in issues] == ["assembly"] and "cannot hover" in issues[0][1]
