"""The node's links, the autopilot, the radio and a GPS receiver of its own (a Clearpath
base's), as the service will open them.

From the profile and the `--autopilot` / `--radio` / `--gps` options this module decides, for
each link: what goes into fieldkit.toml (nothing when the profile's own setting stands), which
serial device the service must be allowed to open (`DeviceAllow=`), whether it needs the
network (then no `PrivateNetwork=`) and which addresses it talks to (`IPAddressAllow=`),
and which udev rule gives a USB adapter its stable name (/dev/autopilot, /dev/xbee,
/dev/gps).
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from fieldkit.deploy import DeployError, layout
from fieldkit.robot.profiles import Profile

#: pymavlink's network connection strings (`udpin:0.0.0.0:14550`, `tcp:10.0.0.2:5760`).
_MAVLINK_NETWORK = re.compile(r"(udpin|udpout|udpbcast|udp|tcpin|tcp):(?P<host>[^:]*)(:\d+)?$")

#: Addresses a field network uses: loopback, private ranges, link-local, multicast and
#: broadcast (a WiFi mesh, the Solo's own 10.1.1.0/24). Whatever else the node would talk
#: to is named on its command line, and added.
PRIVATE_NETWORKS = (
    "localhost",
    "link-local",
    "multicast",
    "10.0.0.0/8",
    "172.16.0.0/12",
    "192.168.0.0/16",
    "255.255.255.255/32",
    "fc00::/7",
)

#: Hosts that need no entry of their own: "every interface" when bound, or the loopback
#: that PRIVATE_NETWORKS already allows.
_ANY = ("", "0.0.0.0", "::", "localhost")


@dataclass(frozen=True)
class UsbRule:
    """A udev rule: the adapter with this USB id is /dev/NAME, for dialout."""

    name: str  # "autopilot", "xbee" or "gps": /dev/NAME
    vendor: str  # four lower-case hex digits
    product: str


@dataclass(frozen=True)
class Link:
    """One link of the node as the service opens it."""

    what: str  # "autopilot", "radio" or "gps", for messages and the option (--what)
    config: str | None  # the value for fieldkit.toml; None: the profile's own setting
    device: str | None = None  # the serial device the service opens
    network: bool = False  # the link is IP: the service needs the network
    hosts: tuple[str, ...] = ()  # the addresses or host names the URL names
    usb: UsbRule | None = None  # the udev rule that names its adapter
    described: str = ""  # how messages name it: "/dev/ttyUSB0 (the solo profile's XBee)"


def autopilot_link(profile: Profile, given: str | None) -> tuple[Link, list[str]]:
    """The autopilot link: `--autopilot` (a serial device or a pymavlink network URL), else
    /dev/autopilot when the profile gives its USB id and a serial link, else the profile's
    `autopilot.url`. Also the warnings (a USB id the link cannot use)."""
    warnings: list[str] = []
    url = profile.autopilot.url
    usb = profile.usb.autopilot
    if given is not None:
        return _autopilot(given, given, f"--autopilot {given}"), warnings
    if usb is not None:
        if _serial_path(url) is not None:
            vendor, product = usb.split(":")
            device = str(layout.AUTOPILOT_DEVICE)
            rule = UsbRule("autopilot", vendor, product)
            described = f"{device} (USB {usb}, the {profile.name} profile's [usb] autopilot)"
            return Link("autopilot", device, device=device, usb=rule, described=described), []
        warnings.append(
            f"the {profile.name} profile's usb.autopilot ({usb}) is not used: its autopilot "
            f"is reached over {url}, not a serial port"
        )
    link = _autopilot(url, None, f"{url} (the {profile.name} profile's autopilot.url)")
    return link, warnings


def _autopilot(url: str, config: str | None, described: str) -> Link:
    """A pymavlink connection string: a serial device (`/dev/ttyACM0`, `/dev/ttyS1,57600`)
    or a network URL."""
    path = _serial_path(url)
    if path is not None:
        return Link("autopilot", config, device=path, described=described)
    m = _MAVLINK_NETWORK.match(url)
    if m is None:
        raise DeployError(
            f"autopilot {url!r}: neither a serial device (/dev/...) nor a network URL\n"
            "hint: give a device such as /dev/ttyACM0, or udpin:0.0.0.0:14550, "
            "udpout:HOST:PORT, tcp:HOST:PORT"
        )
    return Link("autopilot", config, network=True, hosts=(m["host"],), described=described)


def radio_link(profile: Profile, given: str | None) -> tuple[Link, list[str]]:
    """The radio link: `--radio` (`none`, an XBee's `serial://` URL or path, `udp://...`),
    else /dev/xbee when the profile gives its XBee's USB id, else the profile's [radio]."""
    warnings: list[str] = []
    settings = profile.radio
    usb = profile.usb.radio
    if given is not None:
        return _radio(given), warnings
    if usb is not None:
        if settings.kind == "xbee":
            vendor, product = usb.split(":")
            device = str(layout.RADIO_DEVICE)
            url = f"serial://{device}?baud={settings.baud}&api={settings.api_mode}"
            rule = UsbRule("xbee", vendor, product)
            described = f"{device} (USB {usb}, the {profile.name} profile's [usb] radio)"
            return Link("radio", url, device=device, usb=rule, described=described), []
        warnings.append(
            f"the {profile.name} profile's usb.radio ({usb}) is not used: its radio is UDP"
        )
    if settings.kind == "udp":
        described = f"UDP port {settings.udp_port} (the {profile.name} profile's radio)"
        return Link("radio", None, network=True, described=described), warnings
    described = f"{settings.port} (the {profile.name} profile's XBee)"
    return Link("radio", None, device=settings.port, described=described), warnings


def _radio(url: str) -> Link:
    """A `--radio` value, as `fieldkit node --radio` takes it."""
    described = f"--radio {url}"
    if url == "none":
        return Link("radio", url, described=described)
    path = _serial_path(url)
    if path is not None:
        return Link("radio", url, device=path, described=described)
    parts = urlsplit(url)
    if parts.scheme == "serial":
        device = parts.netloc + parts.path
        if not device.startswith("/"):
            raise DeployError(f"--radio {url}: no device path in it (serial:///dev/ttyUSB0)")
        return Link("radio", url, device=device, described=described)
    if parts.scheme in ("udp", "socket", "rfc2217"):
        hosts = [parts.hostname or ""]
        for key, value in parse_qsl(parts.query):
            if key in ("peers", "bind", "iface"):
                hosts += [peer.rsplit(":", 1)[0] for peer in value.split(",")]
        return Link("radio", url, network=True, hosts=tuple(hosts), described=described)
    raise DeployError(
        f"--radio {url}: not a radio URL\nhint: an XBee as serial:///dev/ttyUSB0?baud=230400"
        "&api=2 (or its device path), udp://HOST:PORT, or none"
    )


def gps_link(profile: Profile, given: str | None) -> tuple[Link | None, list[str]]:
    """A GPS receiver on a port of its own (a Clearpath base's; None for an autopilot that
    has its GPS inside): `--gps DEV`, else /dev/gps when the profile gives the receiver's USB
    id, else the profile's `[gps] port`."""
    settings = profile.gps
    if settings is None:
        if given is not None:
            raise DeployError(
                f"--gps {given}: the {profile.name} profile's GPS is inside its autopilot "
                f"(flavour {profile.autopilot.flavour})\nhint: --gps is for a base with a GPS "
                'receiver of its own (flavour "clearpath", a [gps] table in the profile)'
            )
        return None, []
    if given is not None:
        path = _serial_path(given)
        if path is None or path != given:
            raise DeployError(
                f"--gps {given}: not a serial device path\nhint: give the receiver's device, "
                "such as /dev/ttyUSB1 (its baud is the profile's gps.baud)"
            )
        return Link("gps", given, device=given, described=f"--gps {given}"), []
    usb = profile.usb.gps
    if usb is not None:
        vendor, product = usb.split(":")
        device = str(layout.GPS_DEVICE)
        described = f"{device} (USB {usb}, the {profile.name} profile's [usb] gps)"
        rule = UsbRule("gps", vendor, product)
        return Link("gps", device, device=device, usb=rule, described=described), []
    described = f"{settings.port} (the {profile.name} profile's [gps] port)"
    return Link("gps", None, device=settings.port, described=described), []


def _serial_path(url: str) -> str | None:
    """The device of a serial connection string (`/dev/ttyS1,57600` -> /dev/ttyS1), or None."""
    if not url.startswith("/"):
        return None
    return url.split(",", 1)[0]


def ip_allow_list(links: tuple[Link, ...]) -> tuple[str, ...] | None:
    """`IPAddressAllow=` for these links: the field's private ranges plus every literal address
    the URLs name; None (no IP filter at all) if a URL names a host by name, which only DNS
    at run time can turn into addresses."""
    allowed = list(PRIVATE_NETWORKS)
    for link in links:
        for host in link.hosts:
            if host in _ANY:
                continue
            try:
                address = ipaddress.ip_address(host.strip("[]"))
            except ValueError:
                return None
            if not (address.is_private or address.is_loopback or address.is_multicast):
                allowed.append(str(address))
    return tuple(dict.fromkeys(allowed))


def named_hosts(links: tuple[Link, ...]) -> list[str]:
    """The host names (not addresses) the links' URLs name."""
    names = []
    for link in links:
        for host in link.hosts:
            try:
                ipaddress.ip_address(host.strip("[]"))
            except ValueError:
                if host not in _ANY:
                    names.append(host)
    return names


__all__ = [
    "PRIVATE_NETWORKS",
    "Link",
    "UsbRule",
    "autopilot_link",
    "gps_link",
    "ip_allow_list",
    "named_hosts",
    "radio_link",
]
