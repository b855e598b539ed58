"""The operator's signing key and the swarm's encryption key, as files in a key directory.

`fieldkit keys init DIR` writes three files:

* `operator.key`: the operator's Ed25519 private key (PEM, PKCS8), mode 0600. It signs
  updates and stays on the operator's laptop: a robot never holds it, so a captured robot
  cannot forge an update.
* `operator.pub`: its public half (PEM, SubjectPublicKeyInfo). Robots check signatures with it.
* `swarm.key`: 32 random bytes, the ChaCha20-Poly1305 key the swarm shares, as one text line
  `fieldkit-swarm-key-v1 <64 hex digits>`, mode 0600. Robots need it to decrypt updates.

Loading a key checks everything a wrong file can get wrong (missing, another kind of key, a
public key where the private one is expected, garbage, a secret readable by others) and says
which file, what is wrong and what to do (`KeyFileError`).
"""

from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)

from fieldkit.errors import FieldkitError

#: The file names in a key directory.
OPERATOR_KEY = "operator.key"
OPERATOR_PUB = "operator.pub"
SWARM_KEY = "swarm.key"

#: The first word of a swarm key file: names the format, so a future one can be told apart.
SWARM_KEY_TAG = "fieldkit-swarm-key-v1"
SWARM_KEY_BYTES = 32

#: Permission bits a secret file may not have: any access by the group or by others.
SECRET_MODE_MASK = 0o077

#: Key files are a few hundred bytes; reading more than this means it is not one.
MAX_KEY_FILE_BYTES = 16 * 1024

_SWARM_LINE = re.compile(rf"{SWARM_KEY_TAG} ([0-9a-fA-F]*)")


class KeyFileError(FieldkitError, ValueError):
    """A key file that cannot be used: which file, what is wrong with it, and what to do."""

    def __init__(self, file: Path, problem: str, hint: str) -> None:
        self.file = file
        self.problem = problem
        self.hint = hint
        super().__init__(f"{file}: {problem}\nhint: {hint}")

    def __reduce__(self) -> tuple[type[KeyFileError], tuple[Path, str, str]]:
        """Pickle with all three arguments."""
        return (KeyFileError, (self.file, self.problem, self.hint))


@dataclass(frozen=True)
class KeyPaths:
    """The three files of a key directory."""

    directory: Path

    @property
    def operator_key(self) -> Path:
        """The operator's private signing key (stays on the operator's machine)."""
        return self.directory / OPERATOR_KEY

    @property
    def operator_pub(self) -> Path:
        """The operator's public key (every robot holds it)."""
        return self.directory / OPERATOR_PUB

    @property
    def swarm_key(self) -> Path:
        """The swarm's shared encryption key (every robot holds it)."""
        return self.directory / SWARM_KEY

    @property
    def robot_files(self) -> tuple[Path, Path]:
        """What a robot needs: the public key and the swarm key, never the signing key."""
        return self.operator_pub, self.swarm_key


@dataclass(frozen=True)
class RobotKeys:
    """What a robot holds: the key that checks the operator's signature, and the swarm key."""

    operator_pub: Ed25519PublicKey
    swarm_key: bytes


def init_keys(directory: Path | str) -> KeyPaths:
    """Create a fresh operator key pair and swarm key in `directory` (created if needed).

    Never overwrites: if any of the three files exists, nothing is written and a
    `KeyFileError` names it. Each file is written whole before it appears under its name.
    """
    paths = KeyPaths(Path(directory))
    if paths.directory.exists() and not paths.directory.is_dir():
        raise KeyFileError(paths.directory, "is not a directory", "give a directory for the keys")
    for path in (paths.operator_key, paths.operator_pub, paths.swarm_key):
        if path.exists() or path.is_symlink():
            raise KeyFileError(
                path,
                "already exists (fieldkit never overwrites a key)",
                f"keep using these keys, or run `fieldkit keys init` on another directory "
                f"than {paths.directory}",
            )
    try:
        paths.directory.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as e:
        raise KeyFileError(
            paths.directory, f"cannot create: {e.strerror or e}", "choose a writable directory"
        ) from None
    signing = Ed25519PrivateKey.generate()
    private_pem = signing.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    public_pem = signing.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )
    swarm_line = f"{SWARM_KEY_TAG} {os.urandom(SWARM_KEY_BYTES).hex()}\n".encode()
    _create(paths.operator_key, private_pem, 0o600)
    _create(paths.swarm_key, swarm_line, 0o600)
    _create(paths.operator_pub, public_pem, 0o644)
    return paths


def _create(path: Path, data: bytes, mode: int) -> None:
    """Write `path` with `mode`, never replacing a file: a temporary file, fsync, then a hard
    link to the final name (which fails if the name exists), so a crash never leaves a
    half-written key under the real name."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)  # left by a crash of an earlier process with this pid
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
        try:
            os.fchmod(fd, mode)  # the umask may not widen, but we want exactly this mode
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.link(tmp, path)
    except FileExistsError:
        raise KeyFileError(
            path, "already exists (fieldkit never overwrites a key)", "choose another directory"
        ) from None
    except OSError as e:
        raise KeyFileError(
            path, f"cannot write: {e.strerror or e}", "choose a writable directory"
        ) from None
    finally:
        tmp.unlink(missing_ok=True)


def load_signing_key(directory: Path | str) -> Ed25519PrivateKey:
    """The operator's signing key from `directory/operator.key` (the operator's machine only)."""
    path = Path(directory) / OPERATOR_KEY
    data = _read(path, secret=True, hint=f"create keys with `fieldkit keys init {directory}`")
    text = data.decode("latin-1")
    if "PRIVATE KEY" not in text and "PUBLIC KEY" in text:
        raise KeyFileError(
            path,
            "holds a public key, where the operator's private signing key is expected",
            f"the signing key is the {OPERATOR_KEY} that `fieldkit keys init` wrote",
        )
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except TypeError:  # encrypted with a password
        raise KeyFileError(
            path,
            "is encrypted with a password, which fieldkit does not ask for",
            f"use the unencrypted {OPERATOR_KEY} that `fieldkit keys init` wrote",
        ) from None
    except (ValueError, UnsupportedAlgorithm):
        raise KeyFileError(
            path,
            "is not a PEM private key",
            f"use the {OPERATOR_KEY} that `fieldkit keys init` wrote",
        ) from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyFileError(
            path,
            f"is {_key_kind(key)} private key, not an Ed25519 one",
            "create an Ed25519 key pair with `fieldkit keys init DIR`",
        )
    return key


def load_robot_keys(directory: Path | str) -> RobotKeys:
    """What a robot needs from `directory`: `operator.pub` and `swarm.key` (not the
    signing key, which a robot's key directory should not hold)."""
    directory = Path(directory)
    hint = (
        f"copy {OPERATOR_PUB} and {SWARM_KEY} from the operator's key directory "
        f"(made by `fieldkit keys init DIR`) into {directory}"
    )
    return RobotKeys(
        operator_pub=_load_public(directory / OPERATOR_PUB, hint),
        swarm_key=_load_swarm(directory / SWARM_KEY, hint),
    )


def _load_public(path: Path, hint: str) -> Ed25519PublicKey:
    data = _read(path, secret=False, hint=hint)
    if b"PRIVATE KEY" in data:
        raise KeyFileError(
            path,
            "holds a private key, where the operator's public key is expected",
            f"put the {OPERATOR_PUB} that `fieldkit keys init` wrote here, and keep "
            f"{OPERATOR_KEY} off the robots",
        )
    try:
        key = serialization.load_pem_public_key(data)
    except (ValueError, UnsupportedAlgorithm):
        raise KeyFileError(path, "is not a PEM public key", hint) from None
    if not isinstance(key, Ed25519PublicKey):
        raise KeyFileError(path, f"is {_key_kind(key)} public key, not an Ed25519 one", hint)
    return key


def _load_swarm(path: Path, hint: str) -> bytes:
    data = _read(path, secret=True, hint=hint)
    try:
        text = data.decode("ascii").strip()
    except UnicodeDecodeError:
        text = ""
    match = _SWARM_LINE.fullmatch(text)
    if match is None:
        raise KeyFileError(
            path,
            f"is not a swarm key (one line: `{SWARM_KEY_TAG}` and {2 * SWARM_KEY_BYTES} "
            f"hex digits)",
            hint,
        )
    digits = match.group(1)
    if len(digits) != 2 * SWARM_KEY_BYTES:
        raise KeyFileError(
            path,
            f"holds a key of {len(digits)} hex digits, {2 * SWARM_KEY_BYTES} expected",
            hint,
        )
    return bytes.fromhex(digits)


def _read(path: Path, *, secret: bool, hint: str) -> bytes:
    """The bytes of a key file, after checking it exists, is a file and (for a secret)
    that nobody but its owner can read or write it."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise KeyFileError(path, "missing", hint) from None
    except OSError as e:
        raise KeyFileError(path, f"cannot read: {e.strerror or e}", hint) from None
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError(path, "is not a regular file", hint)
    if secret and st.st_mode & SECRET_MODE_MASK:
        mode = stat.S_IMODE(st.st_mode)
        raise KeyFileError(
            path,
            f"is a secret key readable or writable by others (mode {mode:04o}, 0600 expected)",
            f"chmod 600 {path}",
        )
    try:
        with path.open("rb") as f:
            data = f.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as e:
        raise KeyFileError(path, f"cannot read: {e.strerror or e}", hint) from None
    if len(data) > MAX_KEY_FILE_BYTES:
        raise KeyFileError(path, f"is larger than any key ({MAX_KEY_FILE_BYTES} bytes)", hint)
    return data


def _key_kind(key: object) -> str:
    """`an RSA`, `an X25519`...: the kind of a key for a message (from its class name)."""
    name = type(key).__name__
    for suffix in ("PrivateKey", "PublicKey"):
        name = name.removesuffix(suffix)
    name = {"EllipticCurve": "EC", "DH": "DH", "DSA": "DSA"}.get(name, name)
    article = "an" if name[:1] in "AEFHILMNORSX" else "a"
    return f"{article} {name}"


__all__ = [
    "KeyFileError",
    "KeyPaths",
    "OPERATOR_KEY",
    "OPERATOR_PUB",
    "RobotKeys",
    "SWARM_KEY",
    "init_keys",
    "load_robot_keys",
    "load_signing_key",
]
