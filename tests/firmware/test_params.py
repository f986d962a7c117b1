import struct

import pytest

from groundstation.backends import mavlink_wire as mw
from groundstation.errors import ConfigError
from groundstation.firmware.params import ParamCheck, issues, load_param_file
from tests.peers import ROOT


def test_shipped_parameter_files_load():
    assert load_param_file(ROOT / "firmware_params/crazyflie.toml") == {
        "motorApp.version": 3.0, "supervisor.tmblChckEn": 0.0, "stabilizer.controller": 6.0,
        "motorPowerSet.enable": 0.0}
    assert load_param_file(ROOT / "firmware_params/px4/module_params.toml") == {
        "COM_OF_LOSS_T": 0.1, "PWM_MAIN_DISARM": 900.0}


def test_bad_parameter_files_name_file_and_key(tmp_path):
    bad = tmp_path / "p.toml"
    bad.write_text('[params]\nCOM_OF_LOSS_T = "fast"\n')
    with pytest.raises(ConfigError, match=r"p.toml: params.COM_OF_LOSS_T"):
        load_param_file(bad)
    bad.write_text("[parameters]\nA = 1\n")
    with pytest.raises(ConfigError, match=r"p.toml: params: Field required"):
        load_param_file(bad)
    with pytest.raises(ConfigError, match="file not found"):
        load_param_file(tmp_path / "none.toml")


def test_check_result_and_report():
    f32 = struct.unpack("<f", struct.pack("<f", 0.1))[0]  # 0.1 as it comes back from a float32 parameter
    checks = [ParamCheck(0, "a", "COM_OF_LOSS_T", 0.1, f32), ParamCheck(0, "a", "PWM_MAIN_MIN", 1000, 1100),
              ParamCheck(1, "b", "X", 1, None, note="no heartbeat within 1 s")]
    assert [c.ok for c in checks] == [True, False, False]
    assert issues(checks) == ["module 0 (a): PWM_MAIN_MIN is 1100, must be 1000",
                              "module 1 (b): X is no heartbeat within 1 s, must be 1"]


def test_px4_bytewise_integer_encoding():
    # PX4 puts an INT32 parameter's bytes, not its value, in PARAM_VALUE's float field.
    wire = mw.param_to_wire(1000, 6)
    assert struct.pack("<f", wire) == struct.pack("<i", 1000) and wire != 1000.0
    assert mw.param_from_wire(wire, 6) == 1000.0
    assert mw.param_from_wire(mw.param_to_wire(-5, 6), 6) == -5.0
    assert mw.param_to_wire(0.1, 9) == 0.1 and mw.param_from_wire(0.25, 9) == 0.25  # REAL32 travels as itself
