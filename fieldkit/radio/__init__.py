"""Inter-robot radios for the field node: XBee (XbeeMav-compatible) and UDP.

* `base`    -- the `RadioLink` interface (send / poll / stats / close) and the `IdTable`;
* `xbee`    -- XBee API frames (modes 1 and 2) and the streaming `FrameReader`;
* `xbeemav` -- XbeeMav packets and fragmentation (`XbeeMav`, the packet engine);
* `xbee_core` -- `XBeeCore`, the sans-I/O radio: serial bytes and time in, frames and events out;
* `xbee_serial` -- `XBeeRadio`, that core on a pyserial port;
* `udp`     -- `UdpRadio`, our own datagram format for WiFi meshes and local runs.

`open_radio(url, robot_id)` takes ``serial:///dev/ttyUSB0?baud=230400&api=1``, a device
path, a pyserial URL (``loop://``, ``socket://``...) or ``udp://HOST:PORT``;
`from_profile(profile.radio, robot_id)` builds the radio a device profile describes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .base import IdTable, RadioLink, UnknownSenders, parse_serial
from .udp import UdpRadio
from .xbee_core import XBeeCore
from .xbee_serial import XBeeRadio
from .xbeemav import XbeeMav

if TYPE_CHECKING:
    from fieldkit.robot.profiles import RadioSettings

__all__ = [
    "IdTable",
    "RadioLink",
    "UdpRadio",
    "UnknownSenders",
    "XBeeCore",
    "XBeeRadio",
    "XbeeMav",
    "from_profile",
    "open_radio",
    "parse_serial",
]


def open_radio(url: str, robot_id: int, **kwargs: Any) -> RadioLink:
    """The radio a URL names: `udp://...` is a UdpRadio, anything else an XBeeRadio."""
    if url.startswith("udp://"):
        return UdpRadio.from_url(url, robot_id, **kwargs)
    return XBeeRadio.from_url(url, robot_id, **kwargs)


def from_profile(
    radio: RadioSettings, robot_id: int, *, clock: Callable[[], float] | None = None
) -> RadioLink:
    """The radio of a profile's `[radio]` table.

    An XBee uses `radio.id_map` and drops frames from unlisted serials; with an empty id_map
    it takes sender ids from the packets' sysid/address bytes instead (else it would hear no
    one). UDP broadcasts on `radio.udp_port` to 255.255.255.255.
    """
    if radio.kind == "udp":
        return UdpRadio(robot_id, port=radio.udp_port, group="0.0.0.0")
    options: dict[str, Any] = {} if clock is None else {"clock": clock}
    return XBeeRadio(
        radio.port,
        robot_id,
        baud=radio.baud,
        api_mode=radio.api_mode,
        id_map=radio.id_map,
        unknown="drop" if radio.id_map else "sysid",
        **options,
    )
