"""Real material for the patch tests: three versions of a shipped script and a key set."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

import bvm
from fieldkit.update.keys import SWARM_KEY_BYTES, RobotKeys
from fieldkit.update.release import Release

SCRIPTS = Path(__file__).resolve().parent.parent.parent / "buzz_scripts"
SCRIPT = SCRIPTS / "coverage.bzz"
INCLUDE = SCRIPTS / "include"

#: Edits that make versions 2 and 3 of the script from version 1 (the shipped file).
EDITS = (
    (),
    (("CARROT = 7.5", "CARROT = 7.0"),),
    (("CARROT = 7.5", "CARROT = 6.5"), ("HOTSPOT_PERIOD = 10", "HOTSPOT_PERIOD = 12")),
)


def source(n: int) -> str:
    """The text of version n (1, 2 or 3) of the script."""
    text = SCRIPT.read_text()
    for old, new in EDITS[n - 1]:
        assert old in text, old
        text = text.replace(old, new)
    return text


@cache
def release(n: int) -> Release:
    """Version n of the script, compiled."""
    program = bvm.compile_source(source(n).encode(), str(SCRIPT), [str(INCLUDE)])
    return Release.from_program(program)


@dataclass(frozen=True)
class Keys:
    """An operator's signing key and what robots hold."""

    signing: Ed25519PrivateKey
    robot: RobotKeys


def make_keys(seed: int) -> Keys:
    """A key set derived from `seed` (the same seed, the same keys)."""
    signing = Ed25519PrivateKey.from_private_bytes(bytes([seed]) * 32)
    swarm = bytes([seed ^ 0x5A]) * SWARM_KEY_BYTES
    return Keys(signing, RobotKeys(signing.public_key(), swarm))


KEYS = make_keys(1)
OTHER_KEYS = make_keys(2)
