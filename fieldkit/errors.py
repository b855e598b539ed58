"""fieldkit's error root: every error fieldkit raises on purpose is a `FieldkitError`.

A host (the command line, a ground station, a test) catches `FieldkitError` to report what
the user got wrong without a traceback; anything else is a bug. Errors of the Buzz language
itself (`bvm`) have their own root and are reported the same way.
"""

from __future__ import annotations


class FieldkitError(Exception):
    """Base of every error fieldkit raises deliberately."""


class ConfigError(FieldkitError, ValueError):
    """An invalid parameter (command line, config file), with a message saying which and why."""


class FrameError(FieldkitError, ValueError):
    """Bytes that are not a valid frame of their protocol: `what` is wrong, at byte `offset`.

    `offset` names the first bad byte, counted from the frame's first byte; a frame that ends
    too soon names the byte that is missing (its length). Every protocol's `describe` raises
    it (fieldkit.frames), so a host reports any protocol's bad frame the same way.
    """

    def __init__(self, what: str, offset: int) -> None:
        super().__init__(f"{what} at byte {offset}")
        self.what = what
        self.offset = offset


__all__ = ["ConfigError", "FieldkitError", "FrameError"]
