"""The radio interface the field node drives once per tick, and the XBee serial -> robot id table.

A radio moves one robot's bundles (`fieldkit.robot.bundle.encode` output, the "air bytes") to every
other robot in range and back. The node calls, once per 10 Hz tick:

    for sender, data in radio.poll():      # everything received since the last poll
        bundle = fieldkit.robot.bundle.decode(data)
    radio.send(fieldkit.robot.bundle.encode(my_bundle))

Neither call blocks: `send` queues (the radio paces its frames), `poll` reads what the
operating system already holds and writes what the pacing allows. Hostile or broken input
never raises: it only moves counters in `stats`.

Robot ids on an XBee mesh come from the radios' 64-bit serial numbers, looked up in a table
(`IdTable`, built from a profile's `radio.id_map`), as XbeeMav does with its
Resources/database.xml (docs/bundle.md#addresses). A frame from a serial that is not in the table is
counted as `unknown_senders` and, by default (`unknown="drop"`), dropped: the table is the
fleet list, and a stranger's frames should not be attributed to some robot id. With
`unknown="sysid"` the sender id is taken from the XbeeMav packet itself (the sysid byte of an
'S' packet, the address byte of 'F'/'P'/'A'), which is what XbeeMav effectively does (it
ignores the 64-bit source); `fieldkit.radio.from_profile` picks that policy when the
profile's table is empty. (ROSBuzz takes the sender id from the bundle header in any case,
docs/bundle.md#receive-path; the id `poll` reports is the link-level one.)
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Literal, Protocol, cast, runtime_checkable

UnknownSenders = Literal["drop", "sysid"]
"""What an XBee radio does with frames from serials missing from its `IdTable`."""
UNKNOWN_POLICIES: tuple[str, ...] = ("drop", "sysid")
"""The allowed `UnknownSenders` values."""
MAX_ROBOT_ID = 255
"""ROSBuzz, XbeeMav and MAVLink sysid all hold robot ids in 8 bits (docs/bundle.md#robot-ids)."""


@runtime_checkable
class RadioLink(Protocol):
    """A broadcast radio the field node drives once per tick, without blocking."""

    stats: Counter[str]
    """Event counters (frames in/out, bad frames, unknown senders, ...): see each radio."""

    def send(self, data: bytes) -> None:
        """Queue one bundle's air bytes for broadcast to every robot in range."""
        ...

    def poll(self) -> list[tuple[int, bytes]]:
        """(sender robot id, data) of every packet received since the last poll."""
        ...

    def close(self) -> None:
        """Release the port or socket; the radio is unusable afterwards."""
        ...


def parse_serial(serial: str | int) -> int:
    """An XBee 64-bit serial number as an int: 16 hex digits (any case) or an int."""
    if isinstance(serial, bool):
        raise ValueError(f"not an XBee serial: {serial!r}")
    if isinstance(serial, int):
        value = serial
    elif isinstance(serial, str) and len(serial) == 16:
        try:
            value = int(serial, 16)
        except ValueError:
            raise ValueError(f"not an XBee serial (16 hex digits): {serial!r}") from None
        if not all(ch in "0123456789abcdefABCDEF" for ch in serial):  # int() allows "_", "+"
            raise ValueError(f"not an XBee serial (16 hex digits): {serial!r}")
    else:
        raise ValueError(f"not an XBee serial (16 hex digits): {serial!r}")
    if not 0 <= value < 1 << 64:
        raise ValueError(f"XBee serial out of 64 bits: {serial!r}")
    return value


class IdTable:
    """XBee 64-bit serial -> robot id (0..255), like XbeeMav's database.xml.

    See docs/bundle.md#addresses."""

    def __init__(self, mapping: Mapping[str, int] | Mapping[int, int] | None = None) -> None:
        self._ids: dict[int, int] = {}
        self._serials: dict[int, int] = {}
        for serial, rid in (mapping or {}).items():
            key = parse_serial(serial)
            if isinstance(rid, bool) or not isinstance(rid, int) or not 0 <= rid <= MAX_ROBOT_ID:
                raise ValueError(f"robot id of {serial!r} must be an int in 0..255, got {rid!r}")
            if key in self._ids:
                raise ValueError(f"serial {key:016X} listed twice")
            if rid in self._serials:
                other = self._serials[rid]
                raise ValueError(f"robot id {rid} given to {other:016X} and {key:016X}")
            self._ids[key] = rid
            self._serials[rid] = key

    def lookup(self, serial: int) -> int | None:
        """The robot id of a 64-bit serial, or None if the serial is not in the table."""
        return self._ids.get(serial)

    def __len__(self) -> int:
        """How many radios the table lists."""
        return len(self._ids)

    def __repr__(self) -> str:
        """The table as {serial hex: id}."""
        return f"IdTable({ {f'{k:016X}': v for k, v in self._ids.items()} })"


def check_robot_id(robot_id: int, limit: int = MAX_ROBOT_ID) -> int:
    """`robot_id` if it is an int in 0..limit, else ValueError."""
    if isinstance(robot_id, bool) or not isinstance(robot_id, int) or not 0 <= robot_id <= limit:
        raise ValueError(f"robot id must be an int in 0..{limit}, got {robot_id!r}")
    return robot_id


def check_policy(unknown: str) -> UnknownSenders:
    """`unknown` if it is an `UnknownSenders` value, else ValueError."""
    if unknown not in UNKNOWN_POLICIES:
        raise ValueError(f"unknown-sender policy must be in {UNKNOWN_POLICIES}, got {unknown!r}")
    return cast(UnknownSenders, unknown)  # one of the Literal's values, checked above
