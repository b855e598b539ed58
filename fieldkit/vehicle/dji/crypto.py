"""AES-256 of DJI's OPEN protocol: the app key as the key, ECB blocks over a frame's data.

An encrypted frame (ENC = 1) carries its DATA (command set, id and value, or an ACK's value)
padded to whole 16-byte blocks, each block AES-256-encrypted on its own (ECB, no IV); the
header and both CRCs stay in clear (spec §5). The key is the developer's app key, a string
of 64 hex digits read as 32 bytes. The cipher is the `cryptography` library's: nothing of
AES is written here.
"""

from __future__ import annotations

from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes

from fieldkit.errors import FieldkitError

BLOCK = 16
"""AES block size, bytes: encrypted data is padded to a multiple of it."""
KEY_HEX_DIGITS = 64
"""An app key's length: 64 hex digits, 32 bytes, an AES-256 key."""


class AppKeyError(FieldkitError, ValueError):
    """An app key that is not 64 hex digits; the message never repeats the key."""


def parse_app_key(app_key: str) -> bytes:
    """The 32 key bytes of an app key (64 hex digits, any case, spaces around ignored)."""
    s = app_key.strip()
    if len(s) != KEY_HEX_DIGITS:
        raise AppKeyError(
            f"the DJI app key must be {KEY_HEX_DIGITS} hex digits (as DJI's developer site "
            f"shows it), got {len(s)} characters"
        )
    try:
        return bytes.fromhex(s)
    except ValueError:
        bad = next(i for i, c in enumerate(s) if c not in "0123456789abcdefABCDEF")
        raise AppKeyError(
            f"the DJI app key must be hex digits only; character {bad + 1} is not one"
        ) from None


def padding_for(length: int) -> int:
    """Padding bytes an encrypted DATA of `length` bytes gets: 1..16, never 0 (spec §5.3)."""
    return BLOCK - length % BLOCK


class FrameCipher:
    """AES-256-ECB with one app key: whole blocks in, whole blocks out."""

    def __init__(self, key: bytes) -> None:
        """A cipher for the 32-byte `key` (see `parse_app_key`)."""
        if len(key) != 32:
            raise AppKeyError(f"an AES-256 key is 32 bytes, got {len(key)}")
        self._cipher = Cipher(algorithms.AES(key), modes.ECB())

    @classmethod
    def from_app_key(cls, app_key: str) -> FrameCipher:
        """The cipher of an app key as DJI's developer site gives it (64 hex digits)."""
        return cls(parse_app_key(app_key))

    def encrypt(self, data: bytes) -> bytes:
        """Encrypt whole blocks (`len(data)` a multiple of 16)."""
        if len(data) % BLOCK:
            raise ValueError(f"AES-ECB takes whole {BLOCK}-byte blocks, got {len(data)} bytes")
        enc = self._cipher.encryptor()
        return enc.update(data) + enc.finalize()

    def decrypt(self, data: bytes) -> bytes:
        """Decrypt whole blocks (`len(data)` a multiple of 16)."""
        if len(data) % BLOCK:
            raise ValueError(f"AES-ECB takes whole {BLOCK}-byte blocks, got {len(data)} bytes")
        dec = self._cipher.decryptor()
        return dec.update(data) + dec.finalize()


__all__ = ["AppKeyError", "BLOCK", "FrameCipher", "KEY_HEX_DIGITS", "padding_for", "parse_app_key"]
