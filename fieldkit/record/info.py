"""`fieldkit bag info`: what a recording holds, in the manner of `rosbag info`.

    path:        flight
    storage:     ROS 2 bag, MCAP (1 part)
    duration:    1:02.300 (62.3 s)
    start:       2026-01-01 00:00:00.000 UTC
    end:         2026-01-01 00:01:02.300 UTC
    messages:    8123
    robot:       3
    script:      hello.bzz (sha256 0a1b...)
    ...
    topics:      /autopilot/rx     1234 msgs  fieldkit_msgs/msg/SerialChunk
                 ...

Everything comes from the bag's indexes and its meta: no message but the meta is read, so
it is as quick on an hour's flight as on a minute's.
"""

from __future__ import annotations

import datetime as dt
import tomllib

from fieldkit.record.bag import BagReader

_LABEL = 13  # width of the labels column


def _when(ns: int) -> str:
    """A stamp as UTC date and time, to the millisecond (as a number if no date can say it:
    the stamps of a damaged bag's metadata can be anything)."""
    try:
        t = dt.datetime.fromtimestamp(ns / 1e9, tz=dt.UTC)
    except (OverflowError, OSError, ValueError):
        return f"{ns} ns since the epoch (not a date)"
    return t.strftime("%Y-%m-%d %H:%M:%S.") + f"{t.microsecond // 1000:03d} UTC"


def _duration(seconds: float) -> str:
    """`1:02.300 (62.3 s)`, with hours when there are any."""
    whole, ms = divmod(round(seconds * 1000), 1000)
    h, rest = divmod(whole, 3600)
    m, s = divmod(rest, 60)
    clock = f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"
    return f"{clock}.{ms:03d} ({seconds:.1f} s)"


def _storage(r: BagReader) -> str:
    """`ROS 2 bag, MCAP (2 parts: a, a_1)`."""
    kind = "ROS 1 bag" if r.ros1 else f"ROS 2 bag, {r.storage.upper()}"
    names = ", ".join(p.name for p in r.parts)
    parts = "1 part" if len(r.parts) == 1 else f"{len(r.parts)} parts: {names}"
    return f"{kind} ({parts})"


def _profile(toml: str, config: dict[str, object]) -> str | None:
    """`husky (flavour clearpath)`: the recorded profile's name and autopilot family (None
    for a bag without a profile, a tlog's)."""
    if not toml:
        return None
    try:
        data = tomllib.loads(toml)
    except tomllib.TOMLDecodeError:
        return "unreadable profile text"
    autopilot = data.get("autopilot")
    flavour = config.get("flavour")
    if flavour is None and isinstance(autopilot, dict):
        flavour = autopilot.get("flavour")
    name = data.get("name", "?")
    out = f"{name} (flavour {flavour or '?'})"
    dji = config.get("dji")
    if isinstance(dji, dict) and dji.get("key_fingerprint"):
        out += f", DJI app {dji.get('app_id')} key {dji.get('key_fingerprint')}"
    return out


def describe(r: BagReader) -> str:
    """The `bag info` text of an open recording."""
    meta = r.meta
    config = meta.config()
    lines: list[tuple[str, str]] = [
        ("path", str(r.path)),
        ("storage", _storage(r)),
    ]
    if r.message_count:
        lines += [
            ("duration", _duration(r.duration_s)),
            ("start", _when(r.start_ns)),
            ("end", _when(r.end_ns)),
        ]
    lines += [("messages", str(r.message_count)), ("robot", str(meta.robot_id))]
    profile = _profile(meta.profile_toml, config)
    if profile is not None:
        lines.append(("profile", profile))
    if meta.bo:
        lines.append(("script", f"{meta.script_name or '?'} (sha256 {meta.script_sha256})"))
    else:
        lines.append(("script", "none recorded"))
    if config.get("source") == "tlog":
        lines.append(("source", f"tlog {config.get('tlog', '?')} (no node outputs to verify)"))
    else:
        lines.append(("seed", str(meta.seed)))
        key = meta.key_fingerprint
        lines.append(("keys", f"swarm key {key}" if key else "none"))
    lines.append(("recorded by", f"fieldkit {meta.fieldkit_version}"))
    for note in r.repairs:
        lines.append(("repaired", note))
    topics = r.topics()
    width = max(len(t.name) for t in topics)
    digits = max(len(str(t.count)) for t in topics)
    for i, t in enumerate(topics):
        unit = "msg " if t.count == 1 else "msgs"
        value = f"{t.name:<{width}}  {t.count:>{digits}} {unit}  {t.type}"
        lines.append(("topics" if i == 0 else "", value))
    return "\n".join(f"{label + ':' if label else '':<{_LABEL}}{value}" for label, value in lines)


__all__ = ["describe"]
