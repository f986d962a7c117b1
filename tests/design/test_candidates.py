import json

import pytest

from groundstation.design.candidates import read_candidates, write_candidates
from groundstation.design.enumeration import SamplingPolicy, enumerate_levels
from groundstation.errors import ConfigError


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_round_trip(tmp_path, suffix):
    levels = list(enumerate_levels(6))
    path = tmp_path / f"c{suffix}"
    write_candidates(path, levels, "C4", None)
    back = read_candidates(path)
    assert back.symmetry == "C4" and not back.sampled
    for lv in levels:
        assert list(back.levels[lv.n]) == lv.topologies()


def test_sampled_flag(tmp_path):
    levels = list(enumerate_levels(7, sampling=SamplingPolicy(keep=10)))
    write_candidates(tmp_path / "s.json", levels, "C4", SamplingPolicy(keep=10))
    back = read_candidates(tmp_path / "s.json")
    assert back.sampled and len(back.levels[7]) == 10


def test_malformed_files_name_the_key(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps({"format": "groundstation.candidates/1", "symmetry": "C4", "sampling": None,
                             "levels": [{"n": 2, "topologies": ["oE"]}, {"n": 3, "topologies": ["oE"]}]}))
    with pytest.raises(ConfigError) as err:
        read_candidates(p)
    assert err.value.key == "levels[1]" and str(p) in str(err.value)
    p.write_text(json.dumps({"format": "other"}))
    with pytest.raises(ConfigError, match="format"):
        read_candidates(p)
    with pytest.raises(ConfigError, match="unknown candidates file type"):
        read_candidates(tmp_path / "x.csv")
