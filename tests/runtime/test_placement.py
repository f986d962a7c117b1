"""The placement check: the gravity each module measures against what its mount predicts (the V's two modules
lean opposite ways)."""

import re

import numpy as np

from groundstation.assembly.assembly_file import load_assembly
from groundstation.control.trajectory import euler_zyx
from groundstation.runtime.placement import placement_issues, predicted_up
from tests.peers import ROOT

ASM, _ = load_assembly(ROOT / "configs/assemblies/toy_v2.json")
NAMES = ["module 0 (udp://a)", "module 1 (udp://b)"]


def _measured(body_rotation, order=(0, 1), noise_deg=0.0, seed=0):
    """What the modules at places ``order`` measure (up in their own frames), tilted by ``noise_deg``."""
    rng = np.random.default_rng(seed)
    up = predicted_up(ASM.module_rotations, body_rotation)[list(order)]
    tilt = [euler_zyx(*np.radians(rng.normal(0, noise_deg, 2)), 0.0) for _ in order]
    return np.array([t @ u for t, u in zip(tilt, up, strict=True)])


def test_predicted_up_is_gravity_in_each_module_frame():
    body = euler_zyx(0.1, -0.05, 1.0)
    for r, up in zip(ASM.module_rotations, predicted_up(ASM.module_rotations, body), strict=True):
        np.testing.assert_allclose(up, (body @ r).T @ [0, 0, 1], atol=1e-12)
    # the V's modules lean 22.5 deg each way about x: 45 deg apart
    a, b = predicted_up(ASM.module_rotations, np.eye(3))
    assert abs(np.degrees(np.arccos(a @ b)) - 45.0) < 0.1  # the design's hinge angle is 22.5 deg


def test_right_places_pass_with_accelerometer_error():
    body = euler_zyx(0.03, -0.02, 2.0)  # resting on uneven ground, any heading
    assert placement_issues(_measured(body, noise_deg=2.0, seed=1), ASM.module_rotations, body, NAMES) == []


def test_swapped_links_are_refused_with_both_names():
    body = euler_zyx(0.0, 0.0, -0.7)
    issues = placement_issues(_measured(body, order=(1, 0), noise_deg=1.0), ASM.module_rotations, body, NAMES)
    assert len(issues) == 2
    for i, j in ((0, 1), (1, 0)):
        assert re.fullmatch(rf"{re.escape(NAMES[i])} measures gravity 4\d deg from where its mount at place {i} puts "
                            rf"it; it matches place {j} \({re.escape(NAMES[j])}\): links swapped or in the wrong "
                            rf"order\?", issues[i]), issues[i]


def test_a_module_mounted_otherwise_or_silent():
    body = np.eye(3)
    measured = _measured(body)
    measured[1] = [0.0, 0.0, -1.0]  # upside down
    measured[0] = [np.nan, 0.0, 0.0]
    issues = placement_issues(measured, ASM.module_rotations, body, NAMES)
    assert issues[0] == "module 0 (udp://a) reports no accelerometer reading"
    assert issues[1].startswith("module 1 (udp://b) measures gravity 157 deg from where its mount at place 1 puts "
                                "it; it matches no place")
