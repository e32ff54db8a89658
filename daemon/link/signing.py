"""MAVLink 2 signing: the key file, and the link's two MAVLink objects (one writes, one reads).

Incoming signed frames are checked as the MAVLink signing specification says
(https://mavlink.io/en/guide/message_signing.html, "Accepting signed packets"): the
signature must match the key, and the 48-bit timestamp must be newer than the last
one accepted on the same stream ``(link_id, system, component)``; a stream not seen
before is accepted if its timestamp is at most one minute behind the link's own
clock. The stream timestamps live as long as the link: reconnecting, re-binding a
udpin peer or checking a candidate never forgets them, so a replayed frame is refused
wherever it comes from. pymavlink's own check records a stream's timestamp before
it verifies the signature (a forged frame with a far-future timestamp would then lock
the real autopilot out); :class:`_SignedParser` verifies first.
"""

from __future__ import annotations

import hashlib
import os
import stat
import time
from pathlib import Path
from typing import Any

from uav_depth.core.errors import ConfigError

#: The signing epoch (2015-01-01 00:00 UTC) and unit (10 us) of MAVLink 2 timestamps.
EPOCH_S = 1420070400
TICKS_PER_S = 100_000
#: A new stream may start at most this far (in timestamp ticks) behind our clock: one minute.
NEW_STREAM_WINDOW = 60 * TICKS_PER_S
#: A key file holds 64 hex digits, 32 bytes or a passphrase: anything larger is not a key file.
KEY_FILE_MAX_BYTES = 4096


def load_signing_key(path: Path) -> bytes:
    """The 32-byte MAVLink 2 signing key from ``path``.

    The file holds 64 hex digits, 32 raw bytes, or a passphrase (hashed with
    SHA-256, as MAVProxy's ``signing setup`` and Mission Planner do). A key file
    readable by group or others is refused.
    """
    key = "mavlink.signing_key_file"
    try:
        st = path.stat()
    except FileNotFoundError as exc:
        raise ConfigError(key, "must name an existing file", str(path)) from exc
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(key, "must not be accessible by group or others (chmod 600)",
                          f"{path} with mode {stat.S_IMODE(st.st_mode):04o}")
    if stat.S_ISDIR(st.st_mode):
        raise ConfigError(key, "must name a file, not a directory", str(path))
    if not stat.S_ISREG(st.st_mode) or st.st_size > KEY_FILE_MAX_BYTES:
        raise ConfigError(key, f"must be a regular file of at most {KEY_FILE_MAX_BYTES} bytes",
                          f"{path} ({st.st_size} bytes)")
    try:
        with open(path, "rb") as fh:
            raw = fh.read(KEY_FILE_MAX_BYTES)
    except OSError as exc:   # the service user cannot read it (root-owned 0600): one line, exit 78
        raise ConfigError(key, f"must be readable by this user (uid {os.getuid()}): {exc.strerror}",
                          str(path)) from exc
    text = raw.strip()
    try:
        if len(text) == 64:
            return bytes.fromhex(text.decode("ascii"))
    except (ValueError, UnicodeDecodeError):
        pass
    if len(raw) == 32:
        return raw
    if not text:
        raise ConfigError(key, "must not be empty", str(path))
    return hashlib.sha256(text).digest()


def signing_now() -> int:
    """The MAVLink 2 signing timestamp of now: 10 us units since 2015 (never before 2015)."""
    return int((max(time.time(), EPOCH_S) - EPOCH_S) * TICKS_PER_S)


class _Capture:
    """pymavlink's MAVLink object writes to a file; this one keeps the bytes."""

    buf = b""

    def write(self, buf: bytes) -> None:
        self.buf = bytes(buf)


def _signed_parser_class(base: type) -> type:
    class _SignedParser(base):     # type: ignore[misc, valid-type]
        """A parser whose signature check follows the specification (see the module docstring)."""

        def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:
            s = self.signing
            h = hashlib.sha256(s.secret_key)
            h.update(msgbuf[:-6])
            if h.digest()[:6] != bytes(msgbuf[-6:]):
                return False                                  # not our key: nothing about it is recorded
            tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
            stamp = tlow + (thigh << 32)
            stream = (msgbuf[-13], srcSystem, srcComponent)
            last = s.stream_timestamps.get(stream)
            now = max(s.timestamp, signing_now())
            if (stamp <= last) if last is not None else (stamp + NEW_STREAM_WINDOW < now):
                s.replays = getattr(s, "replays", 0) + 1
                return False                                  # a replay, or a stream from long ago
            s.stream_timestamps[stream] = stamp
            s.timestamp = max(s.timestamp, stamp)
            return True

    return _SignedParser


class Signing:
    """The link's MAVLink objects: ``tx`` packs (and signs) what we send, ``rx`` parses what we receive.

    ``key`` None: no signing (everything is accepted, nothing signed). With a key,
    only frames signed with it are accepted; what we send is signed on link id 0.
    ``fresh_parser()``: a parser for a datagram from a peer not yet bound, sharing
    ``rx``'s stream timestamps (a replay is refused there too).
    """

    def __init__(self, mavlink_module: Any, key: bytes | None, system_id: int, component_id: int):
        self._module = mavlink_module
        self.key = key
        self._system_id, self._component_id = system_id, component_id
        self._parser_class = _signed_parser_class(mavlink_module.MAVLink)
        self.tx = self._make(mavlink_module.MAVLink)
        self.rx = self._make(self._parser_class)
        if key is not None:
            self.tx.signing.sign_outgoing = True

    @property
    def enabled(self) -> bool:
        return self.key is not None

    @property
    def replays(self) -> int:
        """Signed frames with our key refused for their timestamp (a replay)."""
        return getattr(self.rx.signing, "replays", 0)

    def _make(self, cls: type) -> Any:
        mav = cls(_Capture(), self._system_id, self._component_id)
        mav.robust_parsing = True
        if self.key is not None:
            mav.signing.secret_key = self.key
            mav.signing.link_id = 0
            mav.signing.timestamp = signing_now()
        return mav

    def fresh_parser(self) -> Any:
        """A parser with an empty buffer whose signature checks share ``rx``'s memory of every stream."""
        mav = self._make(self._parser_class)
        if self.key is not None:
            mav.signing = self.rx.signing
        return mav

    def reset_stream(self) -> None:
        """A new connection: the byte buffer starts empty; the signing memory stays."""
        signing = self.rx.signing
        self.rx = self._make(self._parser_class)
        self.rx.signing = signing

    def pack(self, msg: Any) -> bytes:
        """The bytes of ``msg`` (signed when signing), advancing the sequence number."""
        buf = msg.pack(self.tx)
        self.tx.seq = (self.tx.seq + 1) % 256
        return buf
