"""MAVLink 2 signing for ``mavsim`` (the simulated autopilot): the key from a file or an
environment variable, and a parser that checks the signature first.

``companion/mavlink/signing.py`` is the companion's twin of this module, line for line below
this docstring: the two programs may not import each other (docs/ARCHITECTURE.md), as a
companion and PX4 each carry their own signing. ``tests/test_layout.py`` keeps the two the
same. docs/SIGNING.md says how to make a key and share it with the autopilot.

The key is 32 bytes written as 64 hexadecimal digits (whitespace ignored), read from a
file (``--signing-key-file``) or from the environment variable named by
``--signing-key-env``, never from a command-line literal (which ``ps`` shows).

pymavlink's own ``check_signature`` stores a packet's timestamp for its stream before
it compares the signature, so one forged packet stamped far in the future would make
every later genuine packet of that stream look replayed. :func:`enable_signing`
installs a check that verifies the signature first and only then applies the
timestamp rule, so a badly signed packet changes nothing.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import os
import stat
import types
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

logger = logging.getLogger(__name__)

__all__ = ["SigningKeyError", "load_signing_key", "enable_signing", "SIGNING_EPOCH_S"]


class SigningKeyError(ValueError):
    """The signing key cannot be had: no source, an unreadable file, not 64 hex digits (names file or variable)."""


#: MAVLink 2 signing timestamps count 10 us units since 2015-01-01T00:00:00Z.
SIGNING_EPOCH_S = 1_420_070_400
_MAX_KEY_FILE_BYTES = 4096


def _parse_key(text: str, where: str) -> bytes:
    hexdigits = "".join(text.split())
    try:
        key = bytes.fromhex(hexdigits)
    except ValueError:
        key = b""
    if len(key) != 32:
        raise SigningKeyError(f"{where}: a signing key must be 64 hexadecimal digits (32 bytes)")
    return key


def load_signing_key(key_file: str | Path | None = None, key_env: str | None = None) -> bytes | None:
    """The 32-byte signing key from ``key_file`` or the variable ``key_env`` (None: signing off).

    Raises
    ------
    SigningKeyError
        Both or a missing source, an unreadable file, or not 64 hex digits (names file or variable).
    """
    if key_file is not None and key_env is not None:
        raise SigningKeyError("give the signing key by file or by environment variable, not both")
    if key_env is not None:
        value = os.environ.get(key_env)
        if value is None:
            raise SigningKeyError(f"environment variable {key_env} (signing key) is not set")
        return _parse_key(value, f"environment variable {key_env}")
    if key_file is None:
        return None
    path = Path(key_file)
    try:
        with path.open("rb") as f:
            raw = f.read(_MAX_KEY_FILE_BYTES + 1)
        mode = path.stat().st_mode
    except OSError as exc:
        raise SigningKeyError(f"{path}: cannot read signing key: {exc.strerror or exc}") from None
    if len(raw) > _MAX_KEY_FILE_BYTES:
        raise SigningKeyError(f"{path}: not a signing key file (larger than {_MAX_KEY_FILE_BYTES} bytes)")
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        logger.warning("%s: signing key file is readable by others (chmod 600 it)", path)
    return _parse_key(raw.decode("ascii", errors="replace"), str(path))


def _check_signature_first(self: mavlink2.MAVLink, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """pymavlink's check with the signature compared before the stream's timestamp is touched."""
    expected = hashlib.sha256(self.signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
        return False
    return mavlink2.MAVLink.check_signature(self, msgbuf, src_system, src_component)


def enable_signing(mav: mavlink2.MAVLink, key: bytes, *, link_id: int, now_s: float) -> None:
    """Sign what ``mav`` packs and reject what it parses unsigned or badly signed.

    Parameters
    ----------
    mav : a pymavlink MAVLink object (an encoder or a parser).
    key : the 32-byte secret key.
    link_id : MAVLink 2 signing link id (0-255).
    now_s : Unix time, seconds: the first outgoing timestamp (as pymavlink's ``setup_signing``).
    """
    signing = mav.signing
    signing.secret_key = bytes(key)
    signing.sign_outgoing = True
    signing.link_id = int(link_id) & 0xFF
    signing.timestamp = max(signing.timestamp, int((max(now_s, SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * 100_000))
    signing.allow_unsigned_callback = None  # unsigned packets are rejected
    mav.check_signature = types.MethodType(_check_signature_first, mav)  # type: ignore[method-assign]
