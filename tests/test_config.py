"""Input files are text: a binary, a device or a huge file is one error naming the file, never read whole."""

import re

import pytest

from groundstation import config
from groundstation.errors import ConfigError


def test_text_toml_and_json_read(tmp_path):
    (tmp_path / "a.toml").write_text('name = "x"\nvalue = 1.5\n')
    (tmp_path / "a.json").write_text('{"a": [1, 2.5]}')
    assert config.read_toml(tmp_path / "a.toml") == {"name": "x", "value": 1.5}
    assert config.read_json(tmp_path / "a.json") == {"a": [1, 2.5]}


@pytest.mark.parametrize("content, problem", [
    (b"\x89MCAP0\r\n\x00\x00\x01", "not a text file"),  # an MCAP log's magic and a record
    (b"name = \"caf\xe9\"\n", "not UTF-8 text (byte 11)"),  # latin-1
])
def test_not_text(tmp_path, content, problem):
    p = tmp_path / "f.toml"
    p.write_bytes(content)
    for read in (config.read_text, config.read_toml, config.read_json):
        with pytest.raises(ConfigError, match=re.escape(f"{p}: {problem}")):
            read(p)


def test_a_file_above_the_cap_is_refused(tmp_path):
    p = tmp_path / "big.toml"
    p.write_text("# comment\n" * (config.MAX_TEXT_BYTES // 10 + 1))
    with pytest.raises(ConfigError, match="big.toml: larger than 4 MiB"):
        config.read_toml(p)
    p.write_text("# comment\n" * (config.MAX_TEXT_BYTES // 10))  # at the cap: read
    assert config.read_toml(p) == {}


def test_dev_zero_is_one_bounded_read():
    """A device that never ends: one read of the cap (it would hang, reading it whole)."""
    with pytest.raises(ConfigError, match="^/dev/zero: not a text file"):
        config.read_toml("/dev/zero")


def test_json_without_non_finite_numbers(tmp_path):
    p = tmp_path / "a.json"
    p.write_text('{"mass_kg": NaN}')
    with pytest.raises(ConfigError, match="a.json: invalid JSON: NaN is not a finite number"):
        config.read_json(p)


def test_json_with_a_key_given_twice(tmp_path):
    """Python's parser keeps the last of two (an edit that left the old value above the new one flew silently)."""
    p = tmp_path / "a.json"
    p.write_text('{"modules": [{"yaw": 0.1, "yaw": 0.2}]}')
    with pytest.raises(ConfigError, match="a.json: invalid JSON: key 'yaw' given twice in one object"):
        config.read_json(p)
    p.write_text('{"a": {"yaw": 1}, "b": {"yaw": 2}}')  # the same key in two objects is no duplicate
    assert config.read_json(p) == {"a": {"yaw": 1}, "b": {"yaw": 2}}


def test_missing_directory_and_unreadable(tmp_path):
    with pytest.raises(ConfigError, match="none.toml: file not found"):
        config.read_toml(tmp_path / "none.toml")
    with pytest.raises(ConfigError, match="is a directory"):
        config.read_toml(tmp_path)
