"""The message types of a fieldkit bag, as rosbags typestores built from the shipped `.msg` files.

A bag holds standard ROS types (`sensor_msgs/NavSatFix`, `sensor_msgs/BatteryState`, from
rosbags' built-in stores), mavros's `mavros_msgs/Mavlink` (no store has it) and our own
`fieldkit_msgs/*`. The last two are defined by the `.msg` files under `fieldkit/record/msgs/`,
in the layout ROS packages use (`PKG/msg/NAME.msg`), so the same files could build a ROS
package; the writers embed the definitions in every bag, so ROS tools and Foxglove read our
bags without having them installed.
"""

from __future__ import annotations

from functools import cache
from importlib import resources
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

MSGS_PACKAGE = "fieldkit.record.msgs"
"""The package whose `PKG/msg/NAME.msg` files define the types no rosbags store has."""

MAVLINK = "mavros_msgs/msg/Mavlink"
META = "fieldkit_msgs/msg/Meta"
SERIAL_CHUNK = "fieldkit_msgs/msg/SerialChunk"
RADIO_FRAME = "fieldkit_msgs/msg/RadioFrame"
TICK = "fieldkit_msgs/msg/Tick"
STREAM_SEND = "fieldkit_msgs/msg/StreamSend"
OUTBOX_PATCH = "fieldkit_msgs/msg/OutboxPatch"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"

OWN_TYPES = (MAVLINK, META, SERIAL_CHUNK, RADIO_FRAME, TICK, OUTBOX_PATCH, STREAM_SEND)
"""The types registered from our `.msg` files."""
USED_TYPES = (
    *OWN_TYPES,
    NAV_SAT_FIX,
    BATTERY_STATE,
    "sensor_msgs/msg/NavSatStatus",
    "std_msgs/msg/Header",
    "builtin_interfaces/msg/Time",
)
"""Every type a bag's messages hold, nested ones included."""


def msg_definitions() -> dict[str, str]:
    """The shipped `.msg` texts by type name (`fieldkit_msgs/msg/Tick`: its text)."""
    root = resources.files(MSGS_PACKAGE)
    found: dict[str, str] = {}
    for package in root.iterdir():
        folder = package / "msg"
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            if entry.name.endswith(".msg"):
                found[f"{package.name}/msg/{entry.name[:-4]}"] = entry.read_text("utf-8")
    return found


@cache
def typestore(ros1: bool) -> Typestore:
    """The typestore of a bag: ROS 1 Noetic's (ROS1 bags) or ROS 2 Humble's, plus ours.

    One per kind for the whole process: building one parses every definition, and rosbags
    caches its generated (de)serializers on the store.
    """
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in msg_definitions().items():
        types.update(get_types_from_msg(text, name))
    missing = set(OWN_TYPES) - set(types)
    if missing:  # a broken install: package data that did not ship
        raise RuntimeError(f"{MSGS_PACKAGE}: no .msg file for {', '.join(sorted(missing))}")
    store.register(types)
    # rosbags generates each type's (de)serializers on its first use: tens of milliseconds,
    # which would land on a node's first recorded tick. Generate them now.
    for name in USED_TYPES:
        store.get_msgdef(name)
    return store


def message_class(ros1: bool, msgtype: str) -> Any:
    """The generated dataclass of `msgtype` in the typestore of that kind of bag."""
    return typestore(ros1).types[msgtype]


__all__ = [
    "BATTERY_STATE",
    "MAVLINK",
    "META",
    "MSGS_PACKAGE",
    "NAV_SAT_FIX",
    "OUTBOX_PATCH",
    "OWN_TYPES",
    "RADIO_FRAME",
    "SERIAL_CHUNK",
    "STREAM_SEND",
    "TICK",
    "USED_TYPES",
    "message_class",
    "msg_definitions",
    "typestore",
]
