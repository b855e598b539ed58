"""Key files: made once, never overwritten, and refused with a clear error when wrong."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec, rsa, x25519
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from fieldkit.update.keys import (
    KeyFileError,
    init_keys,
    load_robot_keys,
    load_signing_key,
)

PEM = serialization.Encoding.PEM


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def private_pem(key: object) -> bytes:
    return key.private_bytes(  # type: ignore[attr-defined]
        PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def public_pem(key: object) -> bytes:
    return key.public_key().public_bytes(  # type: ignore[attr-defined]
        PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )


def replace(path: Path, data: bytes, file_mode: int = 0o600) -> None:
    path.write_bytes(data)
    path.chmod(file_mode)


def key_error(load: object, directory: Path) -> KeyFileError:
    with pytest.raises(KeyFileError) as e:
        load(directory)  # type: ignore[operator]
    return e.value


def test_init_makes_a_working_key_set_with_secret_modes(tmp_path: Path) -> None:
    paths = init_keys(tmp_path / "keys")
    assert sorted(p.name for p in paths.directory.iterdir()) == [
        "operator.key",
        "operator.pub",
        "swarm.key",
    ]
    assert mode(paths.operator_key) == 0o600 and mode(paths.swarm_key) == 0o600
    assert mode(paths.operator_pub) & 0o077 == 0o044  # public: anyone may read it
    signing = load_signing_key(paths.directory)
    robot = load_robot_keys(paths.directory)
    robot.operator_pub.verify(signing.sign(b"m"), b"m")  # the pair matches
    assert len(robot.swarm_key) == 32
    line = paths.swarm_key.read_text()
    assert line == f"fieldkit-swarm-key-v1 {robot.swarm_key.hex()}\n"
    other = load_robot_keys(init_keys(tmp_path / "other").directory)
    assert other.swarm_key != robot.swarm_key


def test_a_robot_needs_only_the_public_key_and_the_swarm_key(tmp_path: Path) -> None:
    paths = init_keys(tmp_path / "op")
    robot_dir = tmp_path / "robot"
    robot_dir.mkdir()
    for path in paths.robot_files:
        replace(robot_dir / path.name, path.read_bytes(), mode(path))
    assert load_robot_keys(robot_dir) == load_robot_keys(paths.directory)
    error = key_error(load_signing_key, robot_dir)
    assert error.problem == "missing" and error.file == robot_dir / "operator.key"


@pytest.mark.parametrize("existing", ["operator.key", "operator.pub", "swarm.key"])
def test_init_never_overwrites_a_key(tmp_path: Path, existing: str) -> None:
    (tmp_path / existing).write_bytes(b"precious")
    with pytest.raises(KeyFileError, match=f"{existing}: already exists"):
        init_keys(tmp_path)
    assert (tmp_path / existing).read_bytes() == b"precious"
    assert [p.name for p in tmp_path.iterdir()] == [existing]  # nothing else written


@pytest.mark.parametrize(
    ("name", "load"),
    [
        ("operator.key", load_signing_key),
        ("operator.pub", load_robot_keys),
        ("swarm.key", load_robot_keys),
    ],
)
def test_a_missing_key_names_the_file_and_the_fix(tmp_path: Path, name: str, load: object) -> None:
    paths = init_keys(tmp_path)
    (tmp_path / name).unlink()
    error = key_error(load, paths.directory)
    assert error.file == tmp_path / name and error.problem == "missing"
    assert "fieldkit keys init" in error.hint
    assert str(error).startswith(f"{tmp_path / name}: missing\nhint: ")


@pytest.mark.parametrize("bad_mode", [0o644, 0o640, 0o604, 0o620, 0o660])
@pytest.mark.parametrize(
    ("name", "load"), [("operator.key", load_signing_key), ("swarm.key", load_robot_keys)]
)
def test_a_secret_readable_by_others_is_refused(
    tmp_path: Path, name: str, load: object, bad_mode: int
) -> None:
    init_keys(tmp_path)
    (tmp_path / name).chmod(bad_mode)
    error = key_error(load, tmp_path)
    assert error.file == tmp_path / name
    assert f"mode {bad_mode:04o}" in error.problem
    assert error.hint == f"chmod 600 {tmp_path / name}"


def test_a_world_readable_public_key_is_fine(tmp_path: Path) -> None:
    init_keys(tmp_path)
    (tmp_path / "operator.pub").chmod(0o644)
    load_robot_keys(tmp_path)


OTHER_PRIVATE = {
    "RSA": lambda: rsa.generate_private_key(public_exponent=65537, key_size=2048),
    "X25519": x25519.X25519PrivateKey.generate,
    "EC": lambda: ec.generate_private_key(ec.SECP256R1()),
}


@pytest.mark.parametrize("kind", sorted(OTHER_PRIVATE))
def test_a_signing_key_of_another_type_is_refused(tmp_path: Path, kind: str) -> None:
    init_keys(tmp_path)
    replace(tmp_path / "operator.key", private_pem(OTHER_PRIVATE[kind]()))
    error = key_error(load_signing_key, tmp_path)
    assert f"{kind} private key, not an Ed25519 one" in error.problem


@pytest.mark.parametrize("kind", sorted(OTHER_PRIVATE))
def test_a_public_key_of_another_type_is_refused(tmp_path: Path, kind: str) -> None:
    init_keys(tmp_path)
    replace(tmp_path / "operator.pub", public_pem(OTHER_PRIVATE[kind]()), 0o644)
    error = key_error(load_robot_keys, tmp_path)
    assert f"{kind} public key, not an Ed25519 one" in error.problem


def test_a_public_key_where_the_signing_key_is_expected_is_refused(tmp_path: Path) -> None:
    paths = init_keys(tmp_path)
    replace(paths.operator_key, paths.operator_pub.read_bytes())
    error = key_error(load_signing_key, tmp_path)
    assert "holds a public key" in error.problem


def test_a_private_key_where_the_public_key_is_expected_is_refused(tmp_path: Path) -> None:
    paths = init_keys(tmp_path)
    replace(paths.operator_pub, paths.operator_key.read_bytes(), 0o600)
    error = key_error(load_robot_keys, tmp_path)
    assert "holds a private key" in error.problem
    assert "off the robots" in error.hint


def test_a_password_protected_signing_key_is_refused(tmp_path: Path) -> None:
    init_keys(tmp_path)
    pem = Ed25519PrivateKey.generate().private_bytes(
        PEM, serialization.PrivateFormat.PKCS8, serialization.BestAvailableEncryption(b"pw")
    )
    replace(tmp_path / "operator.key", pem)
    assert "password" in key_error(load_signing_key, tmp_path).problem


@pytest.mark.parametrize(
    ("name", "load", "data"),
    [
        ("operator.key", load_signing_key, b"garbage\n"),
        ("operator.key", load_signing_key, b""),
        ("operator.key", load_signing_key, b"-----BEGIN PRIVATE KEY-----\nAAAA\n"),
        ("operator.pub", load_robot_keys, b"garbage\n"),
        ("operator.pub", load_robot_keys, b"\xff" * 40),
        ("swarm.key", load_robot_keys, b"garbage\n"),
        ("swarm.key", load_robot_keys, b"\x8f" * 32),  # 32 raw bytes: not the text format
        ("swarm.key", load_robot_keys, b"fieldkit-swarm-key-v2 " + b"ab" * 32),
        ("swarm.key", load_robot_keys, b"fieldkit-swarm-key-v1 " + b"zz" * 32),
        ("swarm.key", load_robot_keys, b"ab" * 32),
        ("operator.key", load_signing_key, b"x" * 20_000),
    ],
)
def test_garbage_in_a_key_file_is_refused(
    tmp_path: Path, name: str, load: object, data: bytes
) -> None:
    init_keys(tmp_path)
    replace(tmp_path / name, data)
    error = key_error(load, tmp_path)
    assert error.file == tmp_path / name
    assert error.problem.startswith("is ")
    assert error.hint


@pytest.mark.parametrize("digits", [0, 2, 62, 66, 128])
def test_a_swarm_key_of_the_wrong_length_is_refused(tmp_path: Path, digits: int) -> None:
    init_keys(tmp_path)
    replace(tmp_path / "swarm.key", b"fieldkit-swarm-key-v1 " + b"a" * digits + b"\n")
    if digits == 0:  # the tag alone: not the format
        assert "not a swarm key" in key_error(load_robot_keys, tmp_path).problem
        return
    error = key_error(load_robot_keys, tmp_path)
    assert error.problem == f"holds a key of {digits} hex digits, 64 expected"


def test_a_directory_in_place_of_a_key_is_refused(tmp_path: Path) -> None:
    init_keys(tmp_path)
    (tmp_path / "swarm.key").unlink()
    (tmp_path / "swarm.key").mkdir()
    assert key_error(load_robot_keys, tmp_path).problem == "is not a regular file"
