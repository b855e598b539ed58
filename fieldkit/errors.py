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


__all__ = ["ConfigError", "FieldkitError"]
