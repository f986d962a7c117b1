from pathlib import Path

import numpy as np
import pytest

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.assembly_file import load_assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology
from groundstation.control.trajectory import Attitude, Figure8, FlightPlan, Hover
from groundstation.errors import PreflightError
from groundstation.runtime.closed_loop import FlightVolume, fly_simulated
from sim.pybullet_backend import PyBulletBackend

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("roll_deg", [0.0, -5.0])
def test_toy_assembly_figure8_holds_roll(roll_deg):
    """Paper §VI-B in simulation: the two-module V tracks the figure-8 with roll held at 0 and -5 degrees."""
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position),
                          Figure8(0.6, 8.0, 1.0, 8.0, attitude=Attitude(roll=np.radians(roll_deg))))
        rec = fly_simulated(asm, plan, be)
    m = rec.metrics
    assert not m.crashed
    assert m.max_roll_error_deg <= 1.0
    assert m.pos_rmse_m < 0.01 and m.max_pos_error_m < 0.02
    airborne = np.isin(rec.phase, ("track",))
    roll = np.degrees(np.arctan2(rec.rotation[airborne, 2, 1], rec.rotation[airborne, 2, 2]))
    assert np.all(np.abs(roll - roll_deg) <= 1.0)
    assert rec.position[-1, 2] < 0.1  # landed


def test_cannot_hover_is_reported_before_takeoff():
    weak = ModuleParams(u_max=1.0e6)  # 1.5 N per module for 2.35 N of weight
    asm = Assembly(Topology.from_code("oE"), weak, np.zeros(3))
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 1), 2.0))
        with pytest.raises(PreflightError, match="cannot hover"):
            fly_simulated(asm, plan, be)
        assert be.telemetry().motors.max() == 0


def test_trajectory_outside_volume_is_rejected():
    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    with PyBulletBackend(asm) as be:
        plan = FlightPlan(tuple(be.start_position), Hover((0, 0, 5.0), 2.0))
        with pytest.raises(PreflightError, match="flight volume"):
            fly_simulated(asm, plan, be, volume=FlightVolume())


def test_paper_vi_a_circle_with_identity_attitude():
    """Paper §VI-A: the n = 30 design for 10 random wrenches tracks a circle, orientation error within 3 deg,
    here with mocap-like noise and latency."""
    from groundstation.control.trajectory import Circle
    from sim.pybullet_backend import SimConfig

    asm, _ = load_assembly(ROOT / "configs/assemblies/random10_seed0_n30.json")
    cfg = SimConfig(position_noise=1e-3, attitude_noise=np.radians(0.2), latency=5e-3)
    with PyBulletBackend(asm, cfg) as be:
        rec = fly_simulated(asm, FlightPlan(tuple(be.start_position), Circle((-0.5, 0, 1), 0.5, 8.0, 8.0)), be)
    m = rec.metrics
    assert not m.crashed and m.max_orientation_error_deg < 3.0
    assert m.pos_rmse_m < 0.02


def test_a_roll_target_it_cannot_hover_at_is_named_with_those_it_can():
    """``simulate --roll 20``: the V hovers within 9 deg of level; before, "the assembly cannot hover" named no roll."""
    from groundstation.control.model import ControlModel
    from groundstation.runtime.closed_loop import hover_check

    asm, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
    model = ControlModel.from_assembly(asm)
    hover_check(model, FlightPlan((0, 0, 0.03), Hover((0, 0, 1), 2.0, Attitude(roll=np.radians(-8.9)))))
    with pytest.raises(PreflightError, match=r"^roll target 20 deg: the assembly cannot hover held at it \(best hover "
                                             r"wrench misses by .*\); it hovers at roll targets from -9.0 to 9.0 deg$"):
        hover_check(model, FlightPlan((0, 0, 0.03), Hover((0, 0, 1), 2.0, Attitude(roll=np.radians(20.0)))))


def test_a_plan_leaving_the_volume_names_both_in_plain_numbers():
    """A volume from a config's geofence holds numpy floats: the message read "[np.float64(-3.3), ...]"."""
    from groundstation.runtime.closed_loop import volume_check

    volume = FlightVolume(tuple(np.array([-3.3, -3.3, 0.0])), tuple(np.array([3.3, 3.3, 0.5])))
    with pytest.raises(PreflightError) as refused:
        volume_check(FlightPlan((0.0, 0.0, 0.0), Hover((0, 0, 1.0), 1.0)), volume)
    assert "along z" in str(refused.value) and "np." not in str(refused.value)
    assert "the volume is [-3.3, -3.3, 0.0]..[3.3, 3.3, 0.5]" in str(refused.value)
