"""Where a Buzz global lives in translated code: as a Python global of the same name."""

from __future__ import annotations

import keyword
import re

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")


def python_name(name: str) -> str | None:
    """The Python global a Buzz global can live under, or None when it needs `_G[...]`."""
    if _IDENT.match(name) and not keyword.iskeyword(name):
        return name
    return None
