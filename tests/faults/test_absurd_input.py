"""Fault table: input that is valid by type but absurd (a take-off of 1e7 s, gains the loop rate cannot realise,
a mocap latency the stale bound cannot see, nan and inf in an option, a binary where a text file belongs).

Each row is one line on stderr naming the file and the key (or the option, or the file), exit 2, before anything
is opened: no log file is made, nothing armed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from groundstation.runtime.fly import prepare
from tests.faults.table import Fault, bad_input, rows
from tests.peers import ROOT
from tests.runtime.test_fly import config_with, sitl_config

TOY_ASSEMBLY = str(ROOT / "configs/assemblies/toy_v2.json")
TOY_TASK = str(ROOT / "configs/tasks/toy_push_y.toml")
CRAZYFLIE = 'kind = "crazyflie"\nmodules = ["udp://127.0.0.1:19850", "udp://127.0.0.1:19851"]'


def _refused(cli, args: tuple, *fragments: str, log: Path | None = None) -> None:
    code, out, err = cli(*args)
    assert code == 2 and err.count("\n") == 1 and all(f in err for f in fragments), err
    assert "Traceback" not in err and (log is None or not log.exists())  # nothing opened, never armed


def _fly_refused(cli, tmp_path, config: Path, *fragments: str) -> None:
    log = tmp_path / "x.mcap"
    _refused(cli, ("fly", str(config), "--log", str(log)), str(config), *fragments, log=log)


# -- flight config keys beyond their physical bound ----------------------------------------------------------------
CONFIG_KEYS = [  # id, the flight config's change (as the row's description), the change, what stderr names
    ("takeoff_1e7_s", "takeoff_s = 1e7", {"roll_deg = 0.0": "roll_deg = 0.0\ntakeoff_s = 1e7"}, "trajectory.takeoff_s"),
    ("landing_1e7_s", "landing_s = 1e7", {"roll_deg = 0.0": "roll_deg = 0.0\nlanding_s = 1e7"}, "trajectory.landing_s"),
    ("figure8_period_1e7_s", "period = 1e7", {"period = 8.0": "period = 1e7"}, "trajectory.period"),
    ("takeoff_1e-200_s", "takeoff_s = 1e-200 (its square is 0: a ZeroDivisionError traceback)",
     {"roll_deg = 0.0": "roll_deg = 0.0\ntakeoff_s = 1e-200"}, "trajectory.takeoff_s"),
    ("takeoff_inf", "takeoff_s = inf", {"roll_deg = 0.0": "roll_deg = 0.0\ntakeoff_s = inf"},
     "trajectory.takeoff_s: Input should be a finite number"),
    ("blind_descent_1_mps", "failsafe.blind_descent_mps = 1 (a blind touchdown at 1 m/s)",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nblind_descent_mps = 1.0"}, "failsafe.blind_descent_mps"),
    ("mocap_endpoint_port_70000", "mocap.endpoint on port 70000 (Zenoh's own error named no key)",
     {'endpoint = "tcp/127.0.0.1:8494"': 'endpoint = "tcp/127.0.0.1:70000"'}, "mocap.endpoint"),
    ("mocap_rate_20_hz", "mocap.rate_hz = 20 (one pose rejected was 50 ms of them: a healthy flight landed on 'every "
     "pose rejected')", {"rate_hz = 100": "rate_hz = 20"}, "mocap.rate_hz"),
    ("height_sigma_1_m", "failsafe.max_height_sigma_m = 1 (a blind estimate that far high meets the ground at 1 m/s)",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_height_sigma_m = 1.0"}, "failsafe.max_height_sigma_m"),
    ("position_gain_1e-9_hz", "position_hz = 1e-9", {"position_hz = 0.8": "position_hz = 1e-9"},
     "gains.position_hz"),
    ("roll_target_1e9_deg", "roll_deg = 1e9", {"roll_deg = 0.0": "roll_deg = 1e9"}, "trajectory.roll_deg"),
    ("figure8_size_true", "size = true (lax validation flew it as 1 m)", {"size = 0.6": "size = true"},
     "trajectory.size: expected a number, not true"),
    ("loop_rate_string", 'rate_hz = "250" (lax validation flew it as 250 Hz)', {"rate_hz = 250": 'rate_hz = "250"'},
     "rate_hz: expected a number, not '250'"),
    ("attitude_gain_40_hz", "attitude_hz = 40 at rate_hz = 250", {"attitude_hz = 4.0": "attitude_hz = 40.0"},
     "gains.attitude_hz: 40 Hz"),
    ("attitude_gain_nan", "attitude_hz = nan", {"attitude_hz = 4.0": "attitude_hz = nan"},
     "gains.attitude_hz: Input should be a finite"),
    ("attitude_damping_1e-6", "attitude_zeta = 1e-6", {"attitude_zeta = 0.9": "attitude_zeta = 1e-6"},
     "gains.attitude_hz", "attitude_zeta = 1e-06"),
    ("loop_rate_60_hz", "rate_hz = 60 with the 4 Hz attitude gains", {"rate_hz = 250": "rate_hz = 60"},
     "gains.attitude_hz", "60 Hz (rate_hz)"),
    ("physics_1e9_hz", "backend.physics_hz = 1e9", {"physics_hz = 240": "physics_hz = 1e9"}, "backend.physics_hz"),
    ("physics_10_hz", "backend.physics_hz = 10", {"physics_hz = 240": "physics_hz = 10"}, "gains.position_hz",
     "(backend.physics_hz)"),
    ("motor_lag_10_s", "backend.motor_time_constant = 10", {"motor_time_constant = 0.02": "motor_time_constant = 10"},
     "backend.motor_time_constant"),
    ("link_timeout_1e7_s", "kind crazyflie, link_timeout_s = 1e7",
     {'kind = "sim"': f"{CRAZYFLIE}\nlink_timeout_s = 1e7"}, "backend.link_timeout_s"),
    ("mocap_latency_beyond_stale", "mocap.latency_s = 0.3 with mocap_timeout_s = 0.25",
     {"latency_s = 0.005": "latency_s = 0.3"}, "mocap.latency_s", "failsafe.mocap_timeout_s"),
    ("mocap_noise_1_m", "mocap.position_noise = 1", {"position_noise = 0.0005": "position_noise = 1.0"},
     "mocap.position_noise"),
    ("mocap_timeout_1e7_s", "mocap_timeout_s = 1e7", {"mocap_timeout_s = 0.25": "mocap_timeout_s = 1e7"},
     "failsafe.mocap_timeout_s"),
    ("stall_bound_1e-6_s", "max_stall_s = 1e-6", {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_stall_s = 1e-6"},
     "failsafe.max_stall_s"),
    ("tracking_bound_1e9_m", "max_tracking_error_m = 1e9",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_tracking_error_m = 1e9"}, "failsafe.max_tracking_error_m"),
    ("geofence_1e300_m", "geofence_upper = [1e300, 3.5, 3.5]",
     {"geofence_upper = [3.5, 3.5, 3.5]": "geofence_upper = [1e300, 3.5, 3.5]"}, "failsafe.geofence_upper.0"),
    ("geofence_nan", "geofence_lower = [nan, -3.5, -0.2]",
     {"geofence_lower = [-3.5, -3.5, -0.2]": "geofence_lower = [nan, -3.5, -0.2]"}, "failsafe.geofence_lower.0"),
    ("tilt_failsafe_1e-12_deg", "failsafe.max_tilt_deg = 1e-12 (it armed, then stopped the motors at once: an "
     "emergency stop latches real Crazyflie modules)", {"max_tilt_deg = 75": "max_tilt_deg = 1e-12"},
     "failsafe.max_tilt_deg: Input should be greater than or equal to 20"),
    ("tilt_failsafe_180_deg", "failsafe.max_tilt_deg = 180 (a tilt failsafe that never acts)",
     {"max_tilt_deg = 75": "max_tilt_deg = 180"}, "failsafe.max_tilt_deg: Input should be less than or equal to 90"),
    ("tilt_failsafe_below_the_lean", "failsafe.max_tilt_deg = 25, the controller's lean limit 30 deg",
     {"max_tilt_deg = 75": "max_tilt_deg = 25"}, "failsafe.max_tilt_deg", "gains.max_tilt_deg = 30"),
    ("roll_target_59_deg_no_hover", "roll_deg = 59 and max_tilt_deg = 90 (the V hovers within 9 deg of level; the "
     "refusal named neither file nor key)",
     {"roll_deg = 0.0": "roll_deg = 59.0", "max_tilt_deg = 75": "max_tilt_deg = 90"},
     "trajectory.roll_deg: 59 deg: the assembly cannot hover", "from -9.0 to 9.0 deg"),
    ("disturbance_bound_1e-12", "failsafe.max_disturbance_mps2 = 1e-12 (the motors stopped 0.1 s after arming)",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_disturbance_mps2 = 1e-12"}, "failsafe.max_disturbance_mps2"),
    ("blind_descent_1e-12_mps", "failsafe.blind_descent_mps = 1e-12 (on a mocap loss the motors stopped 0.55 m up)",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nblind_descent_mps = 1e-12"}, "failsafe.blind_descent_mps"),
    ("height_sigma_1e-12_m", "failsafe.max_height_sigma_m = 1e-12 (no blind landing: the motors stop where mocap is "
     "lost)", {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_height_sigma_m = 1e-12"}, "failsafe.max_height_sigma_m"),
    ("position_sigma_1e-12_m", "failsafe.max_position_sigma_m = 1e-12 (likewise)",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_position_sigma_m = 1e-12"}, "failsafe.max_position_sigma_m"),
    ("tracking_bound_1e-12_m", "max_tracking_error_m = 1e-12 (it landed as it took off)",
     {"max_tilt_deg = 75": "max_tilt_deg = 75\nmax_tracking_error_m = 1e-12"}, "failsafe.max_tracking_error_m"),
    ("link_loss_1e-12", "kind crazyflie, max_link_loss = 1e-12 (one lost packet lands it)",
     {'kind = "sim"': CRAZYFLIE, "max_tilt_deg = 75": "max_tilt_deg = 75\nmax_link_loss = 1e-12"},
     "failsafe.max_link_loss"),
]
for _name, _what, _changes, *_fragments in CONFIG_KEYS:
    def _case(cli, tmp_path, changes=_changes, fragments=_fragments):
        _fly_refused(cli, tmp_path, config_with(tmp_path, endpoint="tcp/127.0.0.1:8494", **changes), *fragments)
    _case.__name__ = f"f_absurd_{_name}"
    bad_input(f"fly with {_what}", f"exit 2 naming {_fragments[0].split(':')[0]}, never armed")(_case)


# -- options: nan, inf and values beyond the bounds ------------------------------------------------------------------
SIM_PEER = ("sim-peer", TOY_ASSEMBLY, "--duration", "0.2")
"""(Refused before it starts; a short run if not, never one without end.)"""
BRIDGE = ("mocap-bridge", "--system", "mock", "--duration", "0.2")
OPTIONS = [  # id, the command line, what stderr says
    ("simulate_roll_nan", ("simulate", TOY_ASSEMBLY, "--roll", "nan"), "'--roll': 'nan' is not a finite number"),
    ("simulate_roll_20", ("simulate", TOY_ASSEMBLY, "--roll", "20"),
     "--roll: 20 deg: the assembly cannot hover held at it"),
    ("simulate_duration_1e7", ("simulate", TOY_ASSEMBLY, "--duration", "1e7"),
     "--duration: Input should be less than or equal to 3600"),
    ("simulate_physics_1e9_hz", ("simulate", TOY_ASSEMBLY, "--physics-hz", "1e9"), "--physics-hz: 1e+09 Hz is above"),
    ("optimize_starts_nan", ("optimize", TOY_TASK, "--topology", "oS", "--starts", "nan"),
     "'--starts': 'nan' is not a finite number"),
    ("enumerate_sigma_inf", ("enumerate", "5", "--sample", "3", "--sigma", "inf"),
     "'--sigma': 'inf' is not a finite number"),
    ("design_seed_negative", ("design", TOY_TASK, "--sample", "2", "--seed", "-1"),
     "'--seed': -1 is not in the range"),
    ("sim_peer_port_negative", (*SIM_PEER, "--port", "-5"), "'--port': -5 is not in the range 1024<=x<=65535"),
    ("sim_peer_port_0", (*SIM_PEER, "--port", "0"), "'--port': 0 is not in the range 1024<=x<=65535"),
    ("sim_peer_port_65535", (*SIM_PEER, "--port", "65535"), "--port: 65535: module 1 would listen on 65536"),
    ("sim_peer_mocap_port_0", (*SIM_PEER, "--mocap", "tcp/127.0.0.1:0"),
     "'--mocap': tcp/127.0.0.1:0: the port must be 1-65535"),
    ("sim_peer_body_wildcard", (*SIM_PEER, "--body", "**"), "'--body': must be one key chunk, concrete"),
    ("bridge_bodies_wildcard", (*BRIDGE, "--bodies", "**"), "'--bodies': must be one key chunk, concrete"),
    ("bridge_key_prefix_wildcard", (*BRIDGE, "--bodies", "a", "--key-prefix", "mocap/*"),
     "'--key-prefix': must be key chunks separated by '/', concrete"),
    ("bridge_mock_body_nan", (*BRIDGE, "--bodies", "a", "--mock-bodies", "a(nan,0,1,1,0,0,0)"),
     "'--mock-bodies': 'a(nan,0,1,1,0,0,0)': need 7 finite numbers"),
    ("bridge_mock_body_zero_quaternion", (*BRIDGE, "--bodies", "a", "--mock-bodies", "a(0,0,1,0,0,0,0)"),
     "'--mock-bodies': 'a(0,0,1,0,0,0,0)': the quaternion's norm is 0, not 1"),
    ("bridge_endpoint_port_70000", (*BRIDGE, "--bodies", "a", "--endpoint", "tcp/127.0.0.1:70000"),
     "'--endpoint': tcp/127.0.0.1:70000: the port must be 1-65535"),
]
for _name, _args, _fragment in OPTIONS:
    def _case(cli, tmp_path, args=_args, fragment=_fragment):
        _refused(cli, args, fragment)
    _case.__name__ = f"f_absurd_{_name}"
    _shown = " ".join(Path(a).name if "/" in a else a for a in _args)
    bad_input(_shown, f"exit 2, one line naming {_args[-2]}")(_case)


# -- module files beyond a module's physics ---------------------------------------------------------------------------
MODULE_KEYS = [  # id, the module file's change, what stderr names after the file
    ("mass_1e300_kg", "mass = 1e300", {"mass = 0.24 ": "mass = 1e300 "},
     "mass: Input should be less than or equal to 100"),
    ("arm_1e300_m", "l_arm = 1e300", {"l_arm = 0.06 ": "l_arm = 1e300 "},
     "l_arm: Input should be less than or equal to 2"),
    ("drag_torque_1e300", "c_m = 1e300", {"c_m = 1.06e-8 ": "c_m = 1e300 "},
     "c_m: c_m / c_f = 2.58e+306 m is outside"),
    ("inertia_1e-300", "inertia = [1e-300, 1e-300, 1e-300] (optimize took it, exit 0)",
     {"inertia = [6.0e-4, 6.0e-4, 1.1e-3]": "inertia = [1e-300, 1e-300, 1e-300]"}, "inertia: [1e-300, 1e-300, 1e-300]"),
]
for _name, _what, _changes, _fragment in MODULE_KEYS:
    def _case(cli, tmp_path, changes=_changes, fragment=_fragment):
        text = (ROOT / "configs/modules/paper_table2.toml").read_text()
        for old, new in changes.items():
            assert old in text
            text = text.replace(old, new)
        module = tmp_path / "module.toml"
        module.write_text(text)
        _refused(cli, ("optimize", TOY_TASK, "--topology", "oS", "--modules", str(module)), f"{module}: {fragment}")
    _case.__name__ = f"f_absurd_module_{_name}"
    bad_input(f"optimize with a module file of {_what}", f"exit 2 naming the file and {_fragment.split(':')[0]}")(_case)


# -- files that are not text where text belongs ----------------------------------------------------------------------
def _mcap(tmp_path) -> Path:
    """A small, real MCAP file (binary: magic, records with length prefixes)."""
    from mcap.writer import Writer

    path = tmp_path / "flight.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        writer.add_metadata("config", {"rate_hz": "250"})
        writer.finish()
    return path


@bad_input("fly with an MCAP log given as the flight config",
           "exit 2 naming the file: not a text file")
def f_absurd_flight_config_is_an_mcap_log(cli, tmp_path):
    mcap = _mcap(tmp_path)
    _fly_refused(cli, tmp_path, mcap, "not a text file")


@bad_input("fly /dev/zero",
           "exit 2 naming /dev/zero at once (one read of 4 MiB)")
def f_absurd_flight_config_is_dev_zero(cli, tmp_path):
    _fly_refused(cli, tmp_path, Path("/dev/zero"), "not a text file")


@bad_input("fly with a flight config of 5 MiB",
           "exit 2 naming the file: larger than 4 MiB")
def f_absurd_flight_config_of_5_mib(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8494")
    cfg.write_text(cfg.read_text() + "#" * (5 * 2**20))
    _fly_refused(cli, tmp_path, cfg, "larger than 4 MiB")


@bad_input("fly with a flight config in Latin-1",
           "exit 2 naming the file: not UTF-8")
def f_absurd_flight_config_not_utf8(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8494")
    cfg.write_bytes(cfg.read_bytes().replace(b'body = "assembly"', b'body = "assembl\xe9"'))
    _fly_refused(cli, tmp_path, cfg, "not UTF-8 text")


@bad_input("fly with a flight config holding an array nested 5000 deep",
           "exit 2 naming the file: nested deeper than the parser can follow (not a RecursionError traceback)")
def f_absurd_flight_config_nested_5000_deep(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8494")
    cfg.write_text(cfg.read_text() + "\nx = " + "[" * 5000 + "]" * 5000 + "\n")
    _fly_refused(cli, tmp_path, cfg, "invalid TOML: nested deeper than the parser can follow")


@bad_input("simulate an assembly file holding a list nested 100000 deep",
           "exit 2 naming the file: nested deeper than the parser can follow")
def f_absurd_assembly_nested_100000_deep(cli, tmp_path):
    asm = tmp_path / "deep.json"
    asm.write_text("[" * 100000 + "]" * 100000)
    _refused(cli, ("simulate", str(asm)), f"{asm}: invalid JSON: nested deeper than the parser can follow")


@bad_input("fly with assembly = /dev/zero",
           "exit 2 naming the config, assembly and /dev/zero")
def f_absurd_assembly_is_dev_zero(cli, tmp_path):
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8494", **{TOY_ASSEMBLY: "/dev/zero"})
    _fly_refused(cli, tmp_path, cfg, "assembly: /dev/zero: not a text file")


@bad_input("simulate an MCAP log given as the assembly",
           "exit 2 naming the file: not a text file")
def f_absurd_simulate_assembly_is_an_mcap_log(cli, tmp_path):
    mcap = _mcap(tmp_path)
    _refused(cli, ("simulate", str(mcap)), f"{mcap}: not a text file")


def _toy_assembly_with(tmp_path, key: str, text: str) -> Path:
    """The toy V's assembly file with ``key``'s value written as ``text`` (JSON as it stands in the file)."""
    record = json.loads((ROOT / "configs/assemblies/toy_v2.json").read_text())
    record[key] = "__VALUE__"
    path = tmp_path / f"{key}.json"
    path.write_text(json.dumps(record).replace('"__VALUE__"', text))
    return path


@bad_input("simulate an assembly whose yaw_deg, mass_kg or cost is 10**400 (an integer past any float)",
           "exit 2 naming the file and key: too large for any float (before: an OverflowError traceback, exit 1)")
def f_absurd_assembly_number_past_any_float(cli, tmp_path):
    for key in ("yaw_deg", "mass_kg", "cost"):
        asm = _toy_assembly_with(tmp_path, key, str(10**400))
        _refused(cli, ("simulate", str(asm), "--duration", "1"), f"{asm}: {key}: a number too large for any float")


@bad_input("simulate an assembly whose yaw_deg is false, mass_kg \"0.48\" or an angle a string",
           "exit 2 naming the file and key: not a number (before: numpy took them as numbers and it flew)")
def f_absurd_assembly_strings_and_booleans_for_numbers(cli, tmp_path):
    angles = json.loads((ROOT / "configs/assemblies/toy_v2.json").read_text())["angles_deg"]
    for key, text, said in (("yaw_deg", "false", "false"), ("mass_kg", '"0.48"', '"0.48"'),
                            ("angles_deg", json.dumps([str(angles[0]), *angles[1:]]), f'"{angles[0]}"')):
        asm = _toy_assembly_with(tmp_path, key, text)
        _refused(cli, ("simulate", str(asm), "--duration", "1"), f"{asm}: {key}: not a number: {said}")


@bad_input("design --figures naming a file that exists, or a path in a symlink loop",
           "exit 2 naming --figures and why (before: a FileExistsError / OSError traceback, exit 1)")
def f_absurd_design_figures_not_a_directory(cli, tmp_path):
    (tmp_path / "a-file").write_text("")
    (tmp_path / "loop-a").symlink_to(tmp_path / "loop-b")
    (tmp_path / "loop-b").symlink_to(tmp_path / "loop-a")
    task = str(ROOT / "configs/tasks/toy_push_y.toml")
    for figures, why in ((tmp_path / "a-file", "File exists"), (tmp_path / "loop-a" / "x", "symbolic links")):
        _refused(cli, ("design", task, "--min-modules", "2", "--max-modules", "2", "--figures", str(figures)),
                 f"--figures {figures}: cannot make the directory", why)


@bad_input("enumerate 8 --sample 5 --sigma 1e308 (and 1e-300)",
           "samples as the weights say (uniform, or the most compact first), exit 0 (before: an OverflowError "
           "traceback from sigma squared, and numpy warnings)")
def f_absurd_enumerate_sigma_extremes(cli, tmp_path):
    for sigma in ("1e308", "1e-300"):
        code, out, err = cli("enumerate", "8", "--sample", "5", "--sigma", sigma, "--json")
        assert code == 0 and "Traceback" not in err and "Warning" not in err, err
        last = json.loads(out.splitlines()[-1])
        assert last["n"] == 8 and last["kept"] == 5 and 5 <= last["non_isomorphic"] <= last["available"], out


@bad_input("optimize a task with a wrench weight of 1e308, or a force component of 1e308 N",
           "exit 2 naming the file and key, bounded at 1e6 (before: the weight made the cost inf, `optimize` exit 0 "
           "calling it feasible and writing a file its own loader refused; the force read \"needs inf N\")")
def f_absurd_task_weight_and_force_1e308(cli, tmp_path):
    task = tmp_path / "task.toml"
    for line, key in (("weight = 1e308", "wrench.0.weight"), ("torque = [0.0, 0.0, -1e308]", "wrench.0.torque.2")):
        task.write_text(f"[[wrench]]\nforce = [0.0, 0.36, 0.0]\n{line}\n")
        _refused(cli, ("optimize", str(task), "--topology", "oS"), f"{task}: {key}", "1000000")


@bad_input("optimize with the Python executable given as the task",
           "exit 2 naming the file: not a text file")
def f_absurd_task_is_a_binary(cli, tmp_path):
    binary = str(Path(sys.executable).resolve())
    _refused(cli, ("optimize", binary, "--topology", "oS"), f"{binary}: not a text file")


@bad_input("design with /dev/zero as the task",
           "exit 2 naming /dev/zero at once")
def f_absurd_task_is_dev_zero(cli, tmp_path):
    _refused(cli, ("design", "/dev/zero"), "/dev/zero: not a text file")


def _fifo(tmp_path) -> Path:
    """A named pipe nobody writes to: opening it to read blocks until a writer comes."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    return fifo


def _refused_at_once(args: list[str], fragment: str) -> None:
    """``groundstation ARGS`` as an operator runs it, given 60 s: refused, exit 2, one line (a hang fails here)."""
    proc = subprocess.run([sys.executable, "-m", "groundstation", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and fragment in proc.stderr, proc.stderr


@bad_input("fly and params with log_dir in a symlink loop (fly without --log: the log is named in it; params "
           "keeps the modules' parameter tables there)",
           "exit 2 naming log_dir (before: a RuntimeError traceback, exit 1); fly --log elsewhere never looks at it")
def f_absurd_log_dir_in_a_symlink_loop(cli, tmp_path):
    (tmp_path / "loop-a").symlink_to(tmp_path / "loop-b")
    (tmp_path / "loop-b").symlink_to(tmp_path / "loop-a")
    loop = {'log_dir = "../../out/flights"': f'log_dir = "{tmp_path / "loop-a"}"'}
    cfg = config_with(tmp_path, endpoint="tcp/127.0.0.1:8494", **loop)
    _refused(cli, ("fly", str(cfg)), str(cfg), "log_dir")
    assert prepare(cfg, None, tmp_path / "elsewhere.mcap").log_file == tmp_path / "elsewhere.mcap"
    modules = sitl_config(tmp_path, "crazyflie", 22748, "tcp/127.0.0.1:8495")
    modules.write_text(modules.read_text().replace(*next(iter(loop.items()))))
    _refused(cli, ("params", str(modules)), str(modules), "log_dir", "log directory cannot be resolved")


@bad_input("fly --live on a port another process listens on",
           "exit 2 naming --live and the port, before anything opens (before: the operator was told to connect to "
           "it, the live view's failure only a warning inside the log, exit 0: their Foxglove reached the other "
           "process)")
def f_absurd_live_port_in_use(cli, tmp_path):
    import socket

    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        port = other.getsockname()[1]
        if port < 1024:
            pytest.skip("the kernel gave a port below --live's range")
        log = tmp_path / "x.mcap"
        _refused(cli, ("fly", str(config_with(tmp_path, endpoint="tcp/127.0.0.1:8496")), "--live", str(port),
                       "--log", str(log)), f"--live {port}: cannot listen on tcp/127.0.0.1:{port}", log=log)


@bad_input("fly with a named pipe (FIFO) nobody writes to as the flight config",
           "exit 2 naming the file: not a regular file (before: the open blocked for good, the first Ctrl-C "
           "swallowed)")
def f_absurd_flight_config_is_a_fifo(cli, tmp_path):
    fifo = _fifo(tmp_path)
    _refused_at_once(["fly", str(fifo), "--log", str(tmp_path / "x.mcap")],
                     f"{fifo}: not a regular file (a pipe or socket), expected a text file")
    assert not (tmp_path / "x.mcap").exists()


@bad_input("a FIFO as simulate's and sim-peer's assembly, optimize's task and replay's --rerun-with config",
           "exit 2 naming the file, each (before: each hung)")
def f_absurd_inputs_are_fifos(cli, tmp_path):
    fifo = _fifo(tmp_path)
    what = f"{fifo}: not a regular file (a pipe or socket), expected a text file"
    for args in (["simulate", str(fifo), "--duration", "1"], ["sim-peer", str(fifo), "--duration", "1"],
                 ["optimize", str(fifo), "--topology", "oE"]):
        _refused_at_once(args, what)
    log = _mcap(tmp_path)  # a log to replay (its flight is not rerun: the config is refused first)
    _refused_at_once(["replay", str(log), "--rerun-with", str(fifo)], what)


@bad_input("a Zenoh endpoint that is not one ('junk', 'tcp/'): mocap-bridge --endpoint, sim-peer --mocap, "
           "mocap.endpoint",
           "exit 2 naming the option or the file and key: <protocol>/<address> (before: a zenoh.ZError traceback)")
def f_absurd_zenoh_endpoint(cli, tmp_path):
    what = "is not a Zenoh endpoint: <protocol>/<address>, e.g. tcp/127.0.0.1:7448"
    _refused_at_once(["mocap-bridge", "--system", "mock", "--bodies", "a", "--endpoint", "junk", "--duration", "1"],
                     f"Invalid value for '--endpoint': 'junk' {what}")
    _refused_at_once(["sim-peer", TOY_ASSEMBLY, "--mocap", "tcp/", "--duration", "1"],
                     f"Invalid value for '--mocap': 'tcp/' {what}")
    cfg = config_with(tmp_path, endpoint="junk")
    _fly_refused(cli, tmp_path, cfg, f"mocap.endpoint: 'junk' {what}")


@pytest.mark.parametrize("row", rows(__name__), ids=[f.id for f in rows(__name__)])
def test_fault(row: Fault, cli, tmp_path):
    row.run(cli, tmp_path)
