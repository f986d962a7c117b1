import numpy as np
import pytest

from groundstation.assembly.assembly import Assembly
from groundstation.assembly.module import ModuleParams
from groundstation.assembly.topology import Topology

P = ModuleParams()


def test_flat_pair_mass_inertia_and_dof():
    a = Assembly(Topology.from_code("oE"), P, np.zeros(3))
    assert a.mass == pytest.approx(0.48)
    jx, jy, jz = P.inertia
    expected = np.diag([2 * jx, 2 * jy + 2 * P.mass * P.l_c**2, 2 * jz + 2 * P.mass * P.l_c**2])
    np.testing.assert_allclose(a.inertia, expected)
    assert a.controllable_dof == 4
    assert a.rotor_positions.shape == (8, 3) and list(a.rotor_spin) == [-1, 1, -1, 1] * 2


def test_v_shape_has_five_controllable_dof():
    a = Assembly(Topology.from_code("oS"), P, np.radians([22.5, 0, -45]))
    assert a.controllable_dof == 5


def test_hinges_about_one_axis_only_cannot_be_fully_actuated():
    # A straight chain hinges about y only: every thrust axis stays in the x-z plane, so no force along y.
    chain = Assembly(Topology.from_code("oEE"), P, np.radians([0, 10, -30, 40]))
    assert chain.controllable_dof == 5
    assert np.allclose(chain.allocation[1], 0)
    ell = Assembly(Topology.from_code("oES"), P, np.radians([0, 10, -30, 40]))  # one x hinge, one y hinge
    assert ell.controllable_dof == 6


def test_clearance_of_the_lowest_frame_corner():
    """A flat pair (modules at +-l_c along x, frames level, half extents hx, hz): at rest its lowest corners touch;
    lifted, they clear by the lift; pitched by theta, the far module's outer bottom edge dips by
    (l_c + hx) sin(theta) + hz cos(theta) - hz."""
    from groundstation.rotations import rotvec_to_matrix

    a = Assembly(Topology.from_code("oE"), P, np.zeros(3))
    hx, _, hz = P.frame_half_extents
    np.testing.assert_allclose(np.abs(a.module_positions[:, 0]), P.l_c)
    assert a.resting_height == pytest.approx(hz)
    assert a.clearance(0.0, np.eye(3)) == pytest.approx(0.0, abs=1e-12)
    assert a.clearance(0.1, np.eye(3)) == pytest.approx(0.1)
    theta = np.radians(20.0)
    dip = (P.l_c + hx) * np.sin(theta) + hz * np.cos(theta) - hz
    assert a.clearance(0.1, rotvec_to_matrix([0.0, theta, 0.0])) == pytest.approx(0.1 - dip)
