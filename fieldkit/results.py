"""Result files as fieldkit writes them: the one place that turns results into JSON bytes."""

from __future__ import annotations

import json
from pathlib import Path


def json_text(data: object) -> str:
    """`data` as stable, human-readable JSON: sorted keys, so the same run gives the same bytes."""
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def write_json(path: Path, data: object) -> Path:
    """Write `data` to `path` as `json_text` gives it; returns `path`."""
    path.write_text(json_text(data), encoding="utf-8")
    return path


__all__ = ["json_text", "write_json"]
