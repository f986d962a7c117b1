"""Authenticated mocap: a key shared by the bridge and the ground station, and a MAC on every pose sample.

The tag is HMAC-SHA256 truncated to 128 bits over the Zenoh key expression, the attachment (sequence, stamp, the
challenges echoed) and the payload, so a tag cannot be moved to another body's key or to another pose, stamp or
echo. It proves a sample came from a holder of the key, not when: a captured sample re-sent later, or the stream
held back on the way, still carries valid tags. The echoed challenges say when (a sample was made after the
ground station sent the challenge it echoes: :mod:`groundstation.mocap.codec`), and the subscriber's sequence and
stamp checks reject the rest (an old stamp disagrees with its arrival time, an old sequence is not after the
newest).

The key file holds 32 random bytes as 64 hexadecimal digits on one line, readable by its owner only (like an SSH
private key): ``groundstation mocap-key PATH`` writes one.
"""

from __future__ import annotations

import hmac
import os
import secrets
import stat
from dataclasses import dataclass
from pathlib import Path

from groundstation.errors import UsageError

KEY_BYTES = 32
MIN_DISTINCT_KEY_BYTES = 16
"""Fewest distinct byte values a key file's key may have: 32 random bytes have about 30, fewer than 16 with a
chance under 1e-20; 64 zeros (or any key typed by hand) are not a secret."""
TAG_BYTES = 16
"""HMAC-SHA256 truncated to 128 bits (RFC 2104 section 5 allows truncation to half the hash)."""


@dataclass(frozen=True, repr=False)
class MocapKey:
    """The shared secret (never printed: ``repr`` hides it)."""

    secret: bytes

    def tag(self, key_expr: str, attachment: bytes, payload: bytes) -> bytes:
        """The MAC of one sample on ``key_expr``."""
        # The key expression and the attachment length-prefixed: no shifting bytes between the fields. One-shot
        # hmac.digest runs in C (a third of the cost of building an hmac object per sample).
        expr = key_expr.encode()
        message = b"".join((len(expr).to_bytes(2, "little"), expr, len(attachment).to_bytes(2, "little"), attachment,
                            payload))
        return hmac.digest(self.secret, message, "sha256")[:TAG_BYTES]

    def verify(self, key_expr: str, attachment: bytes, payload: bytes, tag: bytes) -> bool:
        return hmac.compare_digest(self.tag(key_expr, attachment, payload), tag)

    def __repr__(self) -> str:
        return "MocapKey(<secret>)"


def write_key_file(path: str | Path) -> Path:
    """A new random key in ``path`` (mode 0600); refuses to replace an existing file (it may be in use)."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise UsageError(f"{path}: exists; a key in use is never replaced (remove it first)") from None
    except OSError as exc:
        raise UsageError(f"{path}: cannot create the key file: {exc.strerror}") from None
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(secrets.token_hex(KEY_BYTES) + "\n")
    except OSError as exc:
        path.unlink(missing_ok=True)
        raise UsageError(f"{path}: cannot write the key file: {exc.strerror}") from None
    return path


def load_key_file(path: str | Path) -> MocapKey:
    """The key in ``path``; a one-line :class:`UsageError` naming the file if it is missing, readable by others, or
    not 64 hexadecimal digits."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
        if not stat.S_ISREG(mode):
            raise UsageError(f"{path}: not a regular file")
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise UsageError(f"{path}: readable by others (mode {stat.S_IMODE(mode):o}); chmod 600 it")
        with open(path, "rb") as fh:
            text = fh.read(4 * KEY_BYTES).strip()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read the mocap key: {exc.strerror}") from None
    try:
        secret = bytes.fromhex(text.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        secret = b""
    if len(secret) != KEY_BYTES:
        raise UsageError(f"{path}: not a mocap key ({2 * KEY_BYTES} hexadecimal digits, as `groundstation "
                         f"mocap-key` writes)")
    if len(set(secret)) < MIN_DISTINCT_KEY_BYTES:
        raise UsageError(f"{path}: not a random key ({len(set(secret))} distinct bytes of {KEY_BYTES}: typed, not "
                         f"drawn); make one with `groundstation mocap-key`")
    return MocapKey(secret)
