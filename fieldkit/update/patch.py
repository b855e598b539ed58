"""The patch file: a signed, encrypted delta from one script version to the next.

This module owns the bytes (layout and reasons in docs/update.md, "The patch file"):

    header (126 bytes, big-endian)
        magic b"FKUP" | format u8 = 1 | kind u8 (1 update, 2 rollback) | version u32
        | base sha256 (32) | result sha256 (32) | body length u32 | salt (16) | body sha256 (32)
    signature (64)  Ed25519 by the operator's key over the 126 header bytes
    body            update only: ChaCha20-Poly1305 ciphertext (with its 16-byte tag)

The body's plaintext is three length-prefixed bsdiff4 deltas (`u32 len + BSDIFF40 patch`),
of the .bo, the .bdb and the .bpos. Its key is HKDF-SHA256(swarm key, salt,
info=b"fieldkit-update-v1"): fresh per patch (random salt), so the all-zero nonce is never
used twice with one key. The associated data is the header without its last field (the body
hash, which is the hash of the ciphertext and cannot exist before it): the ciphertext only
decrypts under the header it was made for.

The signature covers the header, which holds the body's hash: checking it (`read_header`)
needs only the first 190 bytes, so a robot refuses a forged patch before pulling the rest,
and nothing is decrypted or patched before the signature, the version rules, the base and
the body hash have all been checked (`open_update`).
"""

from __future__ import annotations

import bz2
import hashlib
import os
import struct
from dataclasses import dataclass
from enum import IntEnum

import bsdiff4  # type: ignore[import-untyped]
from cryptography.exceptions import InvalidSignature, InvalidTag
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from bvm.errors import BuzzLoadError
from fieldkit.errors import ConfigError, FieldkitError
from fieldkit.update.keys import SWARM_KEY_BYTES, RobotKeys
from fieldkit.update.release import MAX_RELEASE_BYTES, Release, ReleaseError

MAGIC = b"FKUP"
FORMAT = 1

#: The header's fields, in order (see the module docstring).
HEADER = struct.Struct(">4sBBI32s32sI16s32s")
HEADER_LEN = HEADER.size
#: The associated data of the body's encryption: the header up to its body hash.
AAD_LEN = HEADER_LEN - 32
SIGNATURE_LEN = 64
#: Header and signature: all `read_header` needs.
PREFIX_LEN = HEADER_LEN + SIGNATURE_LEN
SALT_LEN = 16
TAG_LEN = 16
HKDF_INFO = b"fieldkit-update-v1"
#: The key is fresh per patch, so one fixed nonce is never reused with a key.
NONCE = bytes(12)

#: A whole patch larger than this is refused unread: larger than any script's delta could be.
MAX_PATCH_BYTES = 256 * 1024
#: A patch may skip at most this many versions ahead of the current one (fast-forward rule).
MAX_VERSION_STEP = 1000
MAX_VERSION = 0xFFFFFFFF

#: The three deltas of an update's plaintext: .bo, .bdb, .bpos.
PARTS = 3
_PART_NAMES = (".bo", ".bdb", ".bpos")
_U32 = struct.Struct(">I")
#: The smallest body: the AEAD tag around three empty length prefixes.
MIN_BODY_LEN = TAG_LEN + PARTS * _U32.size

BSDIFF_MAGIC = b"BSDIFF40"
BSDIFF_HEADER_LEN = 32
#: One control triple of a BSDIFF40 delta: three 8-byte sign-magnitude integers.
_CONTROL = struct.Struct("<QQQ")
_SIGN = 1 << 63
#: How far a delta's read position in the old file may wander: far past any script.
_MAX_OLD_OFFSET = 1 << 40

#: Reason codes (stable: a robot counts rejections under these names).
REASONS = (
    "truncated",
    "too-large",
    "bad-magic",
    "bad-format",
    "bad-signature",
    "replayed",
    "fast-forward",
    "wrong-base",
    "bad-body",
    "bad-decrypt",
    "bad-delta",
    "bad-result",
    "bad-bytecode",
)


class PatchError(FieldkitError, ValueError):
    """A patch refused: `.reason` is one of REASONS, the message says what was wrong."""

    def __init__(self, reason: str, message: str) -> None:
        assert reason in REASONS, reason
        self.reason = reason
        super().__init__(message)

    def __reduce__(self) -> tuple[type[PatchError], tuple[str, str]]:
        """Pickle with both arguments (a refusal may cross a process boundary)."""
        return (PatchError, (self.reason, str(self)))


class PatchKind(IntEnum):
    """What a patch orders: switch to a new version, or go back from a bad one."""

    UPDATE = 1
    ROLLBACK = 2


@dataclass(frozen=True)
class PatchHeader:
    """A patch's header, its signature checked.

    For a rollback order, `version` and `base_hash` name the version abandoned and
    `result_hash` the one to return to.
    """

    kind: PatchKind
    version: int
    base_hash: str
    result_hash: str
    body_len: int
    body_hash: str
    salt: bytes
    #: The 126 header bytes and the 64 signature bytes, as received.
    raw: bytes
    signature: bytes

    @property
    def total_len(self) -> int:
        """Bytes of the whole patch: header, signature and body."""
        return PREFIX_LEN + self.body_len

    @property
    def digest(self) -> bytes:
        """The patch's 8-byte identity on the air: a SHA-256 prefix of its header and
        signature. The header holds the body's hash, so this names the whole patch, and a
        robot can compute it from the first 190 bytes, before it holds the body."""
        return hashlib.sha256(self.raw + self.signature).digest()[:8]


def make_update(
    base: Release,
    new: Release,
    version: int,
    signing_key: Ed25519PrivateKey,
    swarm_key: bytes,
) -> bytes:
    """The patch that takes a robot running `base` to `new`, as version `version`.

    `PatchError("too-large")` if it would exceed MAX_PATCH_BYTES; `ConfigError` for a version
    outside 1..2**32-1 or a swarm key that is not 32 bytes.
    """
    _check_version_arg(version)
    if len(swarm_key) != SWARM_KEY_BYTES:
        raise ConfigError(f"a swarm key is {SWARM_KEY_BYTES} bytes, not {len(swarm_key)}")
    plaintext = plaintext_of(base, new)
    return _seal(
        PatchKind.UPDATE,
        version,
        base.hash,
        new.hash,
        plaintext,
        signing_key,
        swarm_key,
        salt=os.urandom(SALT_LEN),
    )


def make_rollback(
    abandon_version: int,
    abandon_hash: str,
    to_hash: str,
    signing_key: Ed25519PrivateKey,
) -> bytes:
    """A signed order to leave version `abandon_version` (`abandon_hash`) for `to_hash`.

    It has no body; its salt is zero, so the same order made twice is the same bytes.
    """
    _check_version_arg(abandon_version)
    return _seal(
        PatchKind.ROLLBACK, abandon_version, abandon_hash, to_hash, None, signing_key, None
    )


def _seal(
    kind: PatchKind,
    version: int,
    base_hash: str,
    result_hash: str,
    plaintext: bytes | None,
    signing_key: Ed25519PrivateKey,
    swarm_key: bytes | None,
    *,
    salt: bytes = bytes(SALT_LEN),
) -> bytes:
    """Header, signature and (with a plaintext) encrypted body, from any field values:
    `make_update` and `make_rollback` use it, and tests make patches the operator signed
    but that are wrong inside (a bad delta, a wrong result hash)."""
    base = _hash_bytes(base_hash, "base hash")
    result = _hash_bytes(result_hash, "result hash")
    if plaintext is None:
        body = b""
        body_len = 0
    else:
        assert swarm_key is not None
        body_len = len(plaintext) + TAG_LEN
        if PREFIX_LEN + body_len > MAX_PATCH_BYTES:
            raise PatchError(
                "too-large",
                f"the patch would be {PREFIX_LEN + body_len} bytes, more than any script's "
                f"({MAX_PATCH_BYTES})",
            )
        aad = HEADER.pack(MAGIC, FORMAT, kind, version, base, result, body_len, salt, b"")
        body = ChaCha20Poly1305(_body_key(swarm_key, salt)).encrypt(NONCE, plaintext, aad[:AAD_LEN])
    header = HEADER.pack(
        MAGIC, FORMAT, kind, version, base, result, body_len, salt, hashlib.sha256(body).digest()
    )
    return header + signing_key.sign(header) + body


def read_header(data: bytes, operator_pub: Ed25519PublicKey) -> PatchHeader:
    """The header of a patch whose first PREFIX_LEN bytes at least are in `data`, once its
    fields are in range and its signature checks (the body, if there, is not looked at)."""
    if len(data) < PREFIX_LEN:
        raise PatchError(
            "truncated", f"{len(data)} bytes, shorter than a patch's header ({PREFIX_LEN})"
        )
    raw = bytes(data[:HEADER_LEN])
    signature = bytes(data[HEADER_LEN:PREFIX_LEN])
    magic, fmt, kind, version, base, result, body_len, salt, body_hash = HEADER.unpack(raw)
    if magic != MAGIC:
        raise PatchError("bad-magic", f"not a fieldkit patch (starts {magic!r}, not {MAGIC!r})")
    if fmt != FORMAT:
        raise PatchError("bad-format", f"patch format {fmt}, this fieldkit reads {FORMAT}")
    if kind not in (PatchKind.UPDATE, PatchKind.ROLLBACK):
        raise PatchError("bad-format", f"unknown patch kind {kind}")
    if PREFIX_LEN + body_len > MAX_PATCH_BYTES:
        raise PatchError(
            "too-large",
            f"the header announces a {PREFIX_LEN + body_len}-byte patch, more than any "
            f"script's ({MAX_PATCH_BYTES})",
        )
    if kind == PatchKind.ROLLBACK and body_len != 0:
        raise PatchError("bad-format", f"a rollback order with a {body_len}-byte body")
    if kind == PatchKind.UPDATE and body_len < MIN_BODY_LEN:
        raise PatchError("bad-format", f"an update with a {body_len}-byte body")
    if version == 0:
        raise PatchError("bad-format", "version 0 (versions start at 1)")
    try:
        operator_pub.verify(signature, raw)
    except InvalidSignature:
        raise PatchError(
            "bad-signature", "the signature is not the operator's (forged or corrupted)"
        ) from None
    return PatchHeader(
        kind=PatchKind(kind),
        version=version,
        base_hash=base.hex(),
        result_hash=result.hex(),
        body_len=body_len,
        body_hash=body_hash.hex(),
        salt=salt,
        raw=raw,
        signature=signature,
    )


def check_version(version: int, current_version: int) -> None:
    """The version rules: a patch must be newer than the current version (else it is a
    replay) and at most MAX_VERSION_STEP newer (else a fast-forward that would block every
    later update)."""
    if version <= current_version:
        raise PatchError(
            "replayed", f"version {version} is not newer than the current {current_version}"
        )
    if version > current_version + MAX_VERSION_STEP:
        raise PatchError(
            "fast-forward",
            f"version {version} is more than {MAX_VERSION_STEP} past the current {current_version}",
        )


def open_update(
    data: bytes, *, base: Release, keys: RobotKeys, current_version: int
) -> tuple[PatchHeader, Release]:
    """Everything a robot does with a whole update before it may switch: the header and its
    signature, the version rules, the base, the body hash, decryption, the bounded delta,
    the result's hash, and that the new bytecode loads. The new release, or a PatchError."""
    if len(data) > MAX_PATCH_BYTES:
        raise PatchError(
            "too-large", f"{len(data)} bytes, more than any script's patch ({MAX_PATCH_BYTES})"
        )
    header = read_header(data, keys.operator_pub)
    if header.kind != PatchKind.UPDATE:
        raise PatchError("bad-format", "a rollback order, not an update")
    check_version(header.version, current_version)
    if header.base_hash != base.hash:
        raise PatchError(
            "wrong-base",
            f"built on version {header.base_hash[:12]}, this robot runs {base.hash[:12]}",
        )
    body = bytes(data[PREFIX_LEN:])
    if len(body) < header.body_len:
        raise PatchError(
            "truncated", f"a {len(body)}-byte body, the header announces {header.body_len}"
        )
    if len(body) > header.body_len:
        raise PatchError(
            "bad-body", f"a {len(body)}-byte body, the header announces {header.body_len}"
        )
    if hashlib.sha256(body).hexdigest() != header.body_hash:
        raise PatchError("bad-body", "the body is not the one the operator signed")
    try:
        plaintext = ChaCha20Poly1305(_body_key(keys.swarm_key, header.salt)).decrypt(
            NONCE, body, header.raw[:AAD_LEN]
        )
    except InvalidTag:
        raise PatchError(
            "bad-decrypt", "the body does not decrypt with this swarm key (another swarm's?)"
        ) from None
    release = apply_deltas(base, plaintext)
    if release.hash != header.result_hash:
        raise PatchError(
            "bad-result",
            f"the patched bytecode is {release.hash[:12]}, the header promises "
            f"{header.result_hash[:12]}",
        )
    try:
        release.program(f"<update v{header.version}>")
    except BuzzLoadError as e:
        raise PatchError("bad-bytecode", f"the new bytecode does not load: {e}") from None
    return header, release


def apply_deltas(base: Release, plaintext: bytes) -> Release:
    """The release a decrypted body's three deltas make from `base`: every delta's sizes
    and blocks are bounded and checked before bsdiff4 applies it (`PatchError` otherwise)."""
    deltas = _split(plaintext)
    total = 0
    checked = []
    for name, old, delta in zip(_PART_NAMES, (base.bo, base.bdb, base.bpos), deltas, strict=True):
        size = _check_delta(delta, name, MAX_RELEASE_BYTES - total)
        total += size
        checked.append((name, old, delta, size))
    parts = [_apply(name, old, delta, size) for name, old, delta, size in checked]
    try:
        return Release(*parts)
    except ReleaseError as e:  # unreachable: the sizes were bounded above
        raise PatchError("too-large", str(e)) from None


def plaintext_of(base: Release, new: Release) -> bytes:
    """An update body's plaintext: the three length-prefixed deltas from `base` to `new`."""
    return b"".join(
        _U32.pack(len(d)) + d
        for d in (
            bsdiff4.diff(base.bo, new.bo),
            bsdiff4.diff(base.bdb, new.bdb),
            bsdiff4.diff(base.bpos, new.bpos),
        )
    )


def open_rollback(data: bytes, keys: RobotKeys) -> PatchHeader:
    """A rollback order's header once its signature checks (it has no body)."""
    if len(data) > MAX_PATCH_BYTES:
        raise PatchError("too-large", f"{len(data)} bytes, more than any patch")
    header = read_header(data, keys.operator_pub)
    if header.kind != PatchKind.ROLLBACK:
        raise PatchError("bad-format", "an update, not a rollback order")
    if len(data) != PREFIX_LEN:
        raise PatchError(
            "bad-body", f"a rollback order of {len(data)} bytes, {PREFIX_LEN} expected"
        )
    return header


def _body_key(swarm_key: bytes, salt: bytes) -> bytes:
    """This patch's encryption key, derived from the swarm key and the patch's salt."""
    return HKDF(algorithm=hashes.SHA256(), length=32, salt=salt, info=HKDF_INFO).derive(swarm_key)


def _split(plaintext: bytes) -> list[bytes]:
    """The three length-prefixed deltas of a decrypted body."""
    deltas = []
    pos = 0
    for _ in range(PARTS):
        if pos + _U32.size > len(plaintext):
            raise PatchError("bad-delta", "the body ends inside its delta lengths")
        (n,) = _U32.unpack_from(plaintext, pos)
        pos += _U32.size
        if pos + n > len(plaintext):
            raise PatchError("bad-delta", "a delta runs past the end of the body")
        deltas.append(plaintext[pos : pos + n])
        pos += n
    if pos != len(plaintext):
        raise PatchError("bad-delta", f"{len(plaintext) - pos} bytes after the last delta")
    return deltas


def _offtin(data: bytes, at: int = 0) -> int:
    """A BSDIFF40 integer: 8 bytes little-endian, the top bit the sign (sign-magnitude)."""
    (raw,) = struct.unpack_from("<Q", data, at)
    return -(raw & ~_SIGN) if raw & _SIGN else raw


def _check_delta(delta: bytes, name: str, room: int) -> int:
    """The new size a BSDIFF40 delta produces, after checking, without applying it, that
    bsdiff4 will only read inside its blocks and write inside a result of at most `room`
    bytes: the header's sizes, each bz2 block decompressed with a bounded output, every
    control triple. A delta that decompresses without limit or points anywhere is refused."""
    if len(delta) < BSDIFF_HEADER_LEN or delta[:8] != BSDIFF_MAGIC:
        raise PatchError("bad-delta", f"the {name} delta is not a BSDIFF40 delta")
    ctrl_len, diff_len, new_size = (_offtin(delta, at) for at in (8, 16, 24))
    if ctrl_len < 0 or diff_len < 0 or new_size < 0:
        raise PatchError("bad-delta", f"the {name} delta has a negative size")
    if new_size > room:
        raise PatchError(
            "too-large",
            f"the {name} delta makes {new_size} bytes, more than any script ({MAX_RELEASE_BYTES} "
            f"for the three files)",
        )
    if BSDIFF_HEADER_LEN + ctrl_len + diff_len > len(delta):
        raise PatchError("bad-delta", f"the {name} delta's blocks run past its end")
    at = BSDIFF_HEADER_LEN
    # No-op triples are never written: one triple per output byte is already generous.
    control = _bunzip(delta[at : at + ctrl_len], _CONTROL.size * (new_size + 1), name)
    at += ctrl_len
    diff = _bunzip(delta[at : at + diff_len], new_size, name)
    extra = _bunzip(delta[at + diff_len :], new_size, name)
    if len(control) % _CONTROL.size:
        raise PatchError("bad-delta", f"the {name} delta's control block is cut")
    new_pos = diff_pos = extra_pos = old_pos = 0
    for at in range(0, len(control), _CONTROL.size):
        x, y, z = (_offtin(control, at + k) for k in (0, 8, 16))
        if x < 0 or y < 0:
            raise PatchError("bad-delta", f"the {name} delta copies a negative length")
        new_pos += x + y
        diff_pos += x
        extra_pos += y
        old_pos += x + z
        if new_pos > new_size or diff_pos > len(diff) or extra_pos > len(extra):
            raise PatchError("bad-delta", f"the {name} delta writes or reads past its blocks")
        if abs(old_pos) > _MAX_OLD_OFFSET:
            raise PatchError("bad-delta", f"the {name} delta seeks far outside the old file")
    if (new_pos, diff_pos, extra_pos) != (new_size, len(diff), len(extra)):
        raise PatchError("bad-delta", f"the {name} delta does not fill its result")
    return new_size


def _bunzip(block: bytes, limit: int, name: str) -> bytes:
    """One bz2 stream, decompressed to at most `limit` bytes, with nothing after it."""
    d = bz2.BZ2Decompressor()
    try:
        out = d.decompress(block, max_length=limit + 1)
    except (OSError, ValueError, EOFError):
        raise PatchError("bad-delta", f"the {name} delta has a corrupt block") from None
    if len(out) > limit:
        raise PatchError("bad-delta", f"a block of the {name} delta inflates past its bound")
    if not d.eof or d.unused_data:
        raise PatchError("bad-delta", f"the {name} delta has a cut or padded block")
    return out


def _apply(name: str, old: bytes, delta: bytes, size: int) -> bytes:
    """bsdiff4's patch of a delta `_check_delta` passed; any failure is a bad delta."""
    try:
        new = bsdiff4.patch(old, delta)
    except Exception as e:  # noqa: BLE001 - bsdiff4 raises several kinds on junk
        raise PatchError("bad-delta", f"the {name} delta does not apply: {e}") from None
    if not isinstance(new, bytes) or len(new) != size:
        raise PatchError("bad-delta", f"the {name} delta made other than {size} bytes")
    return new


def _hash_bytes(text: str, what: str) -> bytes:
    """A hex SHA-256 as its 32 bytes."""
    try:
        raw = bytes.fromhex(text)
    except ValueError:
        raw = b""
    if len(raw) != 32:
        raise ConfigError(f"{what} {text!r} is not a hex SHA-256 (64 hex digits)")
    return raw


def _check_version_arg(version: int) -> None:
    if not 1 <= version <= MAX_VERSION:
        raise ConfigError(f"version {version} is outside 1..{MAX_VERSION}")


__all__ = [
    "HEADER_LEN",
    "MAX_PATCH_BYTES",
    "MAX_VERSION_STEP",
    "PREFIX_LEN",
    "PatchError",
    "PatchHeader",
    "PatchKind",
    "REASONS",
    "apply_deltas",
    "check_version",
    "make_rollback",
    "make_update",
    "open_rollback",
    "open_update",
    "plaintext_of",
    "read_header",
]
