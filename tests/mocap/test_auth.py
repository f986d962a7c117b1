"""The shared mocap key: its file, and a tag bound to the key expression, the attachment and the payload."""

import os
import stat
import struct

import numpy as np
import pytest

from groundstation.errors import UsageError
from groundstation.mocap.auth import MocapKey, load_key_file, write_key_file
from groundstation.mocap.codec import PoseSample, Unauthenticated, decode, encode


def test_key_file_round_trip_and_mode(tmp_path):
    path = write_key_file(tmp_path / "mocap.key")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert len(path.read_text().strip()) == 64
    assert load_key_file(path) == load_key_file(path)
    assert path.read_text().strip() not in repr(load_key_file(path))  # never printed
    assert load_key_file(path).secret != load_key_file(write_key_file(tmp_path / "other.key")).secret
    with pytest.raises(UsageError, match="exists; a key in use is never replaced"):
        write_key_file(path)


@pytest.mark.parametrize("content, mode, match", [
    ("00" * 32, 0o644, "readable by others"),
    ("00" * 31, 0o600, "not a mocap key"),
    ("zz" * 32, 0o600, "not a mocap key"),
    (None, 0o600, "cannot read the mocap key"),
    ("00" * 32, 0o600, "not a random key .1 distinct bytes of 32"),  # typed, not drawn
    ("0123456789abcdef" * 4, 0o600, "not a random key .8 distinct bytes of 32"),
])
def test_bad_key_files_are_one_line_errors_naming_the_file(tmp_path, content, mode, match):
    path = tmp_path / "k.key"
    if content is not None:
        path.write_text(content)
        os.chmod(path, mode)
    with pytest.raises(UsageError, match=match) as ex:
        load_key_file(path)
    assert str(path) in str(ex.value) and "\n" not in str(ex.value)


def test_tag_binds_key_expression_attachment_and_payload():
    key = MocapKey(bytes(range(32)))
    sample = PoseSample(7, 1000.25, np.array([0.1, 0.2, 1.0]), np.eye(3), (b"challenger..0001",))
    payload, att = encode(sample, key, "mocap/a/pose")
    back = decode(payload, att, key, "mocap/a/pose")
    assert len(att) == 96 and back.sequence == 7 and back.echoes == (b"challenger..0001",)
    assert decode(payload, att).sequence == 7  # a subscriber without a key reads an authenticated stream
    other, _ = encode(PoseSample(7, 1000.25, np.array([0.1, 0.2, 1.5]), np.eye(3)))
    bad_att = struct.pack("<Qd", 7, 1000.5) + att[16:]
    bad_echo = att[:16] + b"challenger..0002" + att[32:]
    for p, a, k, expr in [(payload, att, key, "mocap/b/pose"),  # moved to another body's key
                          (other, att, key, "mocap/a/pose"),  # another pose under the tag
                          (payload, bad_att, key, "mocap/a/pose"),  # another stamp or sequence
                          (payload, bad_echo, key, "mocap/a/pose"),  # another challenge echoed
                          (payload, att, MocapKey(bytes(32)), "mocap/a/pose"),  # another key
                          (payload, att[:16], key, "mocap/a/pose")]:  # no tag at all
        with pytest.raises(Unauthenticated):
            decode(p, a, k, expr)
