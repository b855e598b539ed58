"""The patch file: the good path, and every attack of issue 14's list refused with its reason.

Patches are made from three versions of a shipped script with real keys and real crypto;
attacks the operator's key cannot make (a wrong delta, a lying result hash) are built with
`_seal`, the one function that writes a patch's bytes, as a compromised build would.
"""

from __future__ import annotations

import bz2
import hashlib
import struct
from functools import cache

import bsdiff4  # type: ignore[import-untyped]
import pytest

from fieldkit.errors import ConfigError
from fieldkit.update import patch as P
from fieldkit.update.patch import (
    HEADER_LEN,
    MAX_PATCH_BYTES,
    MAX_VERSION_STEP,
    PREFIX_LEN,
    PatchError,
    PatchKind,
    make_rollback,
    make_update,
    open_rollback,
    open_update,
    read_header,
)
from fieldkit.update.release import MAX_RELEASE_BYTES, Release

from .patchkit import KEYS, OTHER_KEYS, Keys, release


@cache
def update(base: int, new: int, version: int, keys: Keys = KEYS) -> bytes:
    """The patch from script version `base` to `new`, numbered `version`."""
    return make_update(release(base), release(new), version, keys.signing, keys.robot.swarm_key)


def refused(data: bytes, *, base: int = 1, current: int = 0, keys: Keys = KEYS) -> str:
    """The reason open_update refuses `data` with (the test fails if it accepts it)."""
    with pytest.raises(PatchError) as e:
        open_update(data, base=release(base), keys=keys.robot, current_version=current)
    assert e.value.reason in P.REASONS
    assert str(e.value)  # a message saying what
    return e.value.reason


def sealed(plaintext: bytes, *, result: str | None = None, version: int = 1) -> bytes:
    """An update the operator signed and encrypted around any plaintext."""
    return P._seal(
        PatchKind.UPDATE,
        version,
        release(1).hash,
        result or release(2).hash,
        plaintext,
        KEYS.signing,
        KEYS.robot.swarm_key,
        salt=b"s" * 16,
    )


def offtout(n: int) -> bytes:
    """A BSDIFF40 integer (sign-magnitude little-endian)."""
    return (abs(n) | (1 << 63 if n < 0 else 0)).to_bytes(8, "little")


def delta(control: list[tuple[int, int, int]], diff: bytes, extra: bytes, new_size: int) -> bytes:
    """A BSDIFF40 delta from its parts."""
    c = bz2.compress(b"".join(offtout(x) + offtout(y) + offtout(z) for x, y, z in control))
    d = bz2.compress(diff)
    return (
        b"BSDIFF40"
        + offtout(len(c))
        + offtout(len(d))
        + offtout(new_size)
        + c
        + d
        + (bz2.compress(extra))
    )


def corrupt(data: bytes, at: int) -> bytes:
    """`data` with the byte at `at` inverted."""
    b = bytearray(data)
    b[at] ^= 0xFF
    return bytes(b)


def body(bo_delta: bytes) -> bytes:
    """A plaintext whose .bo delta is `bo_delta` and whose sidecar deltas are genuine."""
    old, new = release(1), release(2)
    parts = (bo_delta, bsdiff4.diff(old.bdb, new.bdb), bsdiff4.diff(old.bpos, new.bpos))
    return b"".join(struct.pack(">I", len(p)) + p for p in parts)


# -- the good path -----------------------------------------------------------------------


def test_an_update_opens_to_exactly_the_new_version() -> None:
    data = update(1, 2, 1)
    header, new = open_update(data, base=release(1), keys=KEYS.robot, current_version=0)
    assert new == release(2)  # .bo, .bdb and .bpos byte for byte
    assert header.kind is PatchKind.UPDATE and header.version == 1
    assert (header.base_hash, header.result_hash) == (release(1).hash, release(2).hash)
    assert header.total_len == len(data) < len(release(2).bo) // 2  # a delta, not a copy
    assert header.body_hash == hashlib.sha256(data[PREFIX_LEN:]).hexdigest()
    assert len(header.digest) == 8


def test_the_header_is_checked_from_the_first_bytes_alone() -> None:
    data = update(1, 2, 1)
    header = read_header(data[:PREFIX_LEN], KEYS.robot.operator_pub)
    assert header == read_header(data, KEYS.robot.operator_pub)
    assert header.digest == read_header(data, KEYS.robot.operator_pub).digest
    assert header.total_len == len(data)


def test_each_patch_has_a_fresh_key_and_its_own_digest() -> None:
    a = make_update(release(1), release(2), 1, KEYS.signing, KEYS.robot.swarm_key)
    b = make_update(release(1), release(2), 1, KEYS.signing, KEYS.robot.swarm_key)
    ha, hb = (read_header(x, KEYS.robot.operator_pub) for x in (a, b))
    assert ha.salt != hb.salt and a[PREFIX_LEN:] != b[PREFIX_LEN:]
    assert ha.digest != hb.digest


def test_a_patch_may_skip_versions_up_to_the_step() -> None:
    data = update(1, 2, 5 + MAX_VERSION_STEP)
    header, _ = open_update(data, base=release(1), keys=KEYS.robot, current_version=5)
    assert header.version == 5 + MAX_VERSION_STEP


def test_a_script_without_sidecars_updates_too() -> None:
    old, new = Release(release(1).bo), Release(release(2).bo)
    data = make_update(old, new, 1, KEYS.signing, KEYS.robot.swarm_key)
    assert open_update(data, base=old, keys=KEYS.robot, current_version=0)[1] == new


# -- bytes changed on the way ------------------------------------------------------------

#: (offset, reason) of a flipped byte in each header field, the signature and the body.
FLIPS = [
    (0, "bad-magic"),
    (3, "bad-magic"),
    (4, "bad-format"),  # format
    (5, "bad-format"),  # kind
    (6, "bad-signature"),  # version, high byte
    (9, "bad-signature"),  # version, low byte
    (10, "bad-signature"),  # base hash
    (41, "bad-signature"),
    (42, "bad-signature"),  # result hash
    (73, "bad-signature"),
    (74, "too-large"),  # body length, high byte
    (77, "bad-signature"),  # body length, low byte
    (78, "bad-signature"),  # salt
    (93, "bad-signature"),
    (94, "bad-signature"),  # body hash
    (125, "bad-signature"),
    (HEADER_LEN, "bad-signature"),  # signature
    (HEADER_LEN + 31, "bad-signature"),
    (PREFIX_LEN - 1, "bad-signature"),
    (PREFIX_LEN, "bad-body"),  # body
    (PREFIX_LEN + 100, "bad-body"),
    (-17, "bad-body"),  # the AEAD tag
    (-1, "bad-body"),
]


@pytest.mark.parametrize(("offset", "reason"), FLIPS)
def test_a_flipped_byte_is_refused_with_its_reason(offset: int, reason: str) -> None:
    data = bytearray(update(1, 2, 1))
    data[offset] ^= 0xFF
    assert refused(bytes(data)) == reason


def test_every_single_bit_flip_in_header_and_signature_is_refused() -> None:
    data = update(1, 2, 1)
    allowed = {"bad-magic", "bad-format", "too-large", "bad-signature"}
    for offset in range(PREFIX_LEN):
        for bit in (0, 7):
            mutated = bytearray(data)
            mutated[offset] ^= 1 << bit
            assert refused(bytes(mutated)) in allowed, (offset, bit)


def test_bit_flips_across_the_body_are_refused() -> None:
    data = update(1, 2, 1)
    for offset in range(PREFIX_LEN, len(data), max(1, (len(data) - PREFIX_LEN) // 200)):
        mutated = bytearray(data)
        mutated[offset] ^= 0x10
        assert refused(bytes(mutated)) == "bad-body", offset


@pytest.mark.parametrize("keep", [0, 1, 4, HEADER_LEN, PREFIX_LEN - 1, PREFIX_LEN, -1])
def test_a_truncated_patch_is_refused(keep: int) -> None:
    data = update(1, 2, 1)
    assert refused(data[:keep]) == "truncated"


def test_an_extended_patch_is_refused() -> None:
    data = update(1, 2, 1)
    assert refused(data + b"\0") == "bad-body"
    assert refused(data + data) == "bad-body"


def test_re_ordered_body_blocks_are_refused() -> None:
    data = update(1, 2, 1)
    body = data[PREFIX_LEN:]
    swapped = body[64:128] + body[:64] + body[128:]
    assert refused(data[:PREFIX_LEN] + swapped) == "bad-body"


def test_the_body_of_another_patch_is_refused() -> None:
    a, b = update(1, 2, 1), update(1, 3, 1)
    assert refused(a[:PREFIX_LEN] + b[PREFIX_LEN:]) == "bad-body"
    assert refused(a[:HEADER_LEN] + b[HEADER_LEN:]) == "bad-signature"


# -- forgeries ---------------------------------------------------------------------------


def test_a_patch_signed_with_another_key_is_refused() -> None:
    forged = make_update(release(1), release(2), 1, OTHER_KEYS.signing, KEYS.robot.swarm_key)
    assert refused(forged) == "bad-signature"
    with pytest.raises(PatchError, match="signature"):
        read_header(forged[:PREFIX_LEN], KEYS.robot.operator_pub)


def test_a_patch_encrypted_with_another_swarm_key_is_refused() -> None:
    other = make_update(release(1), release(2), 1, KEYS.signing, OTHER_KEYS.robot.swarm_key)
    assert refused(other) == "bad-decrypt"


def test_a_header_edited_and_re_signed_by_another_key_is_refused() -> None:
    data = bytearray(update(1, 2, 1))
    data[9] = 200  # a later version...
    data[HEADER_LEN:PREFIX_LEN] = OTHER_KEYS.signing.sign(bytes(data[:HEADER_LEN]))
    assert refused(bytes(data)) == "bad-signature"


# -- version rules and the base ----------------------------------------------------------


def test_the_same_patch_again_is_a_replay() -> None:
    data = update(1, 2, 1)
    open_update(data, base=release(1), keys=KEYS.robot, current_version=0)
    assert refused(data, current=1) == "replayed"


def test_an_older_valid_patch_is_a_replay() -> None:
    # The robot went 1 -> 2 (version 1) -> 3 (version 2); an attacker replays the first.
    assert refused(update(1, 2, 1), base=3, current=2) == "replayed"


def test_a_version_lower_than_the_current_is_refused() -> None:
    assert refused(update(1, 2, 3), current=7) == "replayed"


def test_an_absurdly_higher_version_is_a_fast_forward() -> None:
    assert refused(update(1, 2, 2 + MAX_VERSION_STEP), current=1) == "fast-forward"
    assert refused(update(1, 2, 0xFFFFFFFF), current=1) == "fast-forward"


def test_a_patch_built_on_another_base_is_refused() -> None:
    assert refused(update(1, 2, 1), base=3) == "wrong-base"
    assert refused(update(2, 3, 1), base=1) == "wrong-base"


def test_check_version_bounds() -> None:
    P.check_version(1, 0)
    P.check_version(MAX_VERSION_STEP, 0)
    for version, current, reason in ((0, 0, "replayed"), (1001, 0, "fast-forward")):
        with pytest.raises(PatchError) as e:
            P.check_version(version, current)
        assert e.value.reason == reason


# -- endless data ------------------------------------------------------------------------


def test_a_patch_larger_than_any_script_is_refused_unread() -> None:
    data = update(1, 2, 1)
    endless = data + bytes(MAX_PATCH_BYTES)
    assert refused(endless) == "too-large"


def test_a_header_announcing_an_endless_body_is_refused_before_its_signature() -> None:
    data = bytearray(update(1, 2, 1))
    struct.pack_into(">I", data, 74, 0xFFFFFFFF)  # body length
    with pytest.raises(PatchError) as e:
        read_header(bytes(data[:PREFIX_LEN]), KEYS.robot.operator_pub)
    assert e.value.reason == "too-large"


def test_a_release_too_large_for_a_patch_is_not_made() -> None:
    noise = hashlib.shake_256(b"incompressible").digest(MAX_PATCH_BYTES)
    with pytest.raises(PatchError) as e:
        make_update(release(1), Release(noise), 1, KEYS.signing, KEYS.robot.swarm_key)
    assert e.value.reason == "too-large"


def test_a_signed_delta_claiming_a_result_larger_than_any_script_is_refused() -> None:
    huge = delta([(0, 1, 0)], b"", b"x", MAX_RELEASE_BYTES + 1)
    assert refused(sealed(body(huge))) == "too-large"


def test_a_signed_delta_that_inflates_past_its_bound_is_refused() -> None:
    # A bz2 bomb: the extra block inflates to 64 MiB for a 100-byte result.
    bomb = delta([(0, 100, 0)], b"", b"\0" * (64 << 20), 100)
    assert len(bomb) < 4096
    assert refused(sealed(body(bomb))) == "bad-delta"


# -- what only the operator's key could sign: a broken build -----------------------------

BAD_DELTAS = {
    "junk": b"not a delta at all",
    "magic only": b"BSDIFF40",
    "negative size": b"BSDIFF40" + offtout(-1) + offtout(0) + offtout(10),
    "blocks past the end": b"BSDIFF40" + offtout(1000) + offtout(0) + offtout(10),
    "corrupt bz2": corrupt(
        delta([(0, 1024, 0)], b"", bytes(range(256)) * 4, 1024),
        20 - len(bz2.compress(bytes(range(256)) * 4)),  # inside the extra block's stream
    ),
    "negative copy": delta([(-5, 10, 0)], b"", b"x" * 5, 5),
    "reads past diff": delta([(10, 0, 0)], b"ab", b"", 10),
    "does not fill": delta([(0, 2, 0)], b"", b"ab", 10),
    "cut control": b"BSDIFF40"
    + offtout(len(bz2.compress(b"x" * 5)))
    + offtout(len(bz2.compress(b"")))
    + offtout(0)
    + bz2.compress(b"x" * 5)
    + bz2.compress(b"")
    + bz2.compress(b""),
    "seeks away": delta([(0, 1, 1 << 50), (0, 1, 0)], b"", b"ab", 2),
    "cut block": delta([(0, 2, 0)], b"", b"ab", 2)[:-3],
    "padded block": delta([(0, 2, 0)], b"", b"ab", 2) + b"\0",
}


@pytest.mark.parametrize("name", sorted(BAD_DELTAS))
def test_a_signed_but_broken_delta_is_refused(name: str) -> None:
    assert refused(sealed(body(BAD_DELTAS[name]))) == "bad-delta"


@pytest.mark.parametrize(
    "plaintext",
    [
        b"\0" * 12,  # three empty deltas
        b"\0\0\0\x05abcdefghijkl",  # a length past the end
        b"\0\0\0\x01a\0\0\0\x01b\0\0",  # ends inside a length
        body(bsdiff4.diff(b"a", b"b")) + b"!",  # something after the third
    ],
)
def test_a_signed_body_that_is_not_three_deltas_is_refused(plaintext: bytes) -> None:
    assert refused(sealed(plaintext)) == "bad-delta"


def test_a_signed_update_too_short_to_hold_a_body_is_refused() -> None:
    assert refused(sealed(b"")) == "bad-format"


def test_a_signed_patch_whose_result_is_not_the_promised_one_is_refused() -> None:
    lying = sealed(P.plaintext_of(release(1), release(2)), result=release(3).hash)
    assert refused(lying) == "bad-result"


def test_a_signed_patch_to_bytecode_that_does_not_load_is_refused() -> None:
    junk = Release(b"\x02\0junk")
    data = make_update(release(1), junk, 1, KEYS.signing, KEYS.robot.swarm_key)
    assert refused(data) == "bad-bytecode"


def test_a_rollback_order_is_not_an_update() -> None:
    order = make_rollback(1, release(2).hash, release(1).hash, KEYS.signing)
    assert refused(order) == "bad-format"


# -- rollback orders ---------------------------------------------------------------------


def test_a_rollback_order_opens() -> None:
    order = make_rollback(4, release(2).hash, release(1).hash, KEYS.signing)
    assert len(order) == PREFIX_LEN
    assert order == make_rollback(4, release(2).hash, release(1).hash, KEYS.signing)
    header = open_rollback(order, KEYS.robot)
    assert header.kind is PatchKind.ROLLBACK and header.version == 4
    assert (header.base_hash, header.result_hash) == (release(2).hash, release(1).hash)


def test_a_forged_or_changed_rollback_order_is_refused() -> None:
    order = make_rollback(4, release(2).hash, release(1).hash, KEYS.signing)
    cases = {
        "bad-signature": make_rollback(4, release(2).hash, release(1).hash, OTHER_KEYS.signing),
        "truncated": order[:-1],
        "bad-body": order + b"\0",
        "bad-format": update(1, 2, 1),
    }
    flipped = bytearray(order)
    flipped[50] ^= 1
    cases["bad-signature "] = bytes(flipped)
    for reason, data in cases.items():
        with pytest.raises(PatchError) as e:
            open_rollback(data, KEYS.robot)
        assert e.value.reason == reason.strip(), reason


# -- making patches ----------------------------------------------------------------------


@pytest.mark.parametrize("version", [0, -1, 1 << 32])
def test_a_version_outside_the_field_is_not_made(version: int) -> None:
    with pytest.raises(ConfigError, match="version"):
        make_update(release(1), release(2), version, KEYS.signing, KEYS.robot.swarm_key)


def test_a_bad_swarm_key_or_hash_is_not_made() -> None:
    with pytest.raises(ConfigError, match="swarm key"):
        make_update(release(1), release(2), 1, KEYS.signing, b"short")
    with pytest.raises(ConfigError, match="hex SHA-256"):
        make_rollback(1, "abc", release(1).hash, KEYS.signing)


def test_a_refusal_keeps_its_reason_across_processes() -> None:
    import pickle

    with pytest.raises(PatchError) as e:
        open_update(b"junk", base=release(1), keys=KEYS.robot, current_version=0)
    again = pickle.loads(pickle.dumps(e.value))
    assert (again.reason, str(again)) == ("truncated", str(e.value))
