"""The number types every command's options use: finite floats, non-negative seeds, lists of finite floats."""

import click
import pytest

from groundstation.cli import cli
from groundstation.cli.common import FINITE, SEED, FiniteFloat, FloatList


def _commands(group: click.Group, prefix: str = ""):
    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            yield from _commands(command, f"{prefix}{name} ")
        else:
            yield prefix + name, command


def test_every_float_option_is_finite():
    plain = {(name, p.opts[0]) for name, command in _commands(cli) for p in command.params
             if isinstance(p.type, click.types.FloatParamType) and not isinstance(p.type, FiniteFloat)}
    assert not plain, plain  # click's FLOAT takes nan and inf
    seeds = {name: p.type for name, command in _commands(cli) for p in command.params if p.name == "seed"}
    assert set(seeds) == {"enumerate", "optimize", "design"} and all(t is SEED for t in seeds.values()), seeds


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "NaN", "1e999"])
def test_non_finite_is_refused(value):
    with pytest.raises(click.BadParameter, match="is not a finite number"):
        FINITE.convert(value, None, None)


def test_finite_within_a_range():
    assert FINITE.convert("-1e300", None, None) == -1e300
    degrees = FiniteFloat(-90, 90)
    assert degrees.convert("45", None, None) == 45.0
    with pytest.raises(click.BadParameter, match="not in the range"):
        degrees.convert("91", None, None)


def test_float_list():
    tilts = FloatList(FiniteFloat(-90, 90))
    assert tilts.convert("20, 10,30,5", None, None) == (20.0, 10.0, 30.0, 5.0)
    for bad, why in (("20,nan", "not a finite number"), ("a,b", "not a valid float"), ("100", "not in the range")):
        with pytest.raises(click.BadParameter, match=why):
            tilts.convert(bad, None, None)


def test_the_status_line_says_the_flight_time_out_of_the_plans_and_the_tracking_error():
    from rich.text import Text

    from groundstation.cli.common import status_text
    from groundstation.runtime.flight import Status

    s = Status(t=12.345, phase="track", mocap_age=0.0041, worst_motor=0.456, battery_v=None, overruns=0,
               rate_hz=250.0, planned_s=25.0, position_error_m=0.00312)
    plain = Text.from_markup(status_text(s, 120, "   keys")).plain
    assert plain == "    track t=  12.3 / 25.0 s  error   3.1 mm  250 Hz  mocap  4.1 ms  motor  46%  late 0   keys"
    assert Text.from_markup(status_text(s, 60, "   keys")).plain == plain[:60]  # cut, the hint left out
