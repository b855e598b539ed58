"""`UdpRadio`: bundles over UDP broadcast or multicast, for WiFi meshes and local runs.

Our own format (not XbeeMav's): each datagram is a 10-byte header then one bundle's air bytes.

    offset 0  2 bytes   magic b"FK"
    offset 2  u8        version, 1
    offset 3  u8        flags, sent 0, ignored on receipt (room for later versions)
    offset 4  u16 BE    sender robot id
    offset 6  u32 BE    instance tag: random per UdpRadio, to tell our own echo (same id,
                        same tag) from another radio configured with our id (same id, other
                        tag)
    offset 10           the air bytes (1..MAX_DATA bytes)

URL forms (`UdpRadio.from_url`), HOST being the address every robot sends to:

* ``udp://127.255.255.255:24580`` (or ``udp://localhost:24580``): loopback broadcast, for
  several robots on one machine; binds 127.255.255.255 with SO_REUSEADDR/SO_REUSEPORT so
  every radio on the port hears every datagram (a socket bound to 127.0.0.1 would not see
  broadcasts, and unicast with SO_REUSEPORT reaches only one of the sockets).
* ``udp://192.168.1.255:24580``: a subnet's broadcast address (a WiFi mesh); binds it.
* ``udp://0.0.0.0:24580``: binds every interface, sends to 255.255.255.255 (which Linux
  sends out of the default route's interface only: prefer the subnet broadcast).
* ``udp://239.255.0.1:24580?iface=192.168.1.5&ttl=1``: multicast group; binds the port on
  every interface and joins the group on `iface` (default: the kernel's choice).
* any of them with ``?peers=10.0.0.2:24580,10.0.0.3`` sends to those unicast addresses
  instead (meshes that drop broadcasts); a peer without a port uses the URL's port.
* ``?bind=ADDR`` overrides the bound address.

Counters (`stats`): datagrams_out, bytes_out, datagrams_in, bytes_in, delivered,
bad_datagrams (short, bad magic or version, empty), echoes (our own datagrams coming back),
id_conflicts (another radio using our robot id: dropped), io_errors (send or receive errors,
e.g. a network that is down; never raised).
"""

from __future__ import annotations

import ipaddress
import random
import socket
import struct
from collections import Counter
from collections.abc import Sequence
from typing import Any
from urllib.parse import parse_qsl, urlsplit

MAGIC = b"FK"
"""The first two bytes of every datagram."""
VERSION = 1
"""The header version this module writes and accepts."""
HEADER = struct.Struct(">2sBBHI")
"""magic, version, flags, robot id, instance tag."""
DEFAULT_PORT = 24580
"""The profiles' default `radio.udp_port`."""
LOOPBACK_BROADCAST = "127.255.255.255"
"""The default group: every radio on this machine."""
MAX_DATA = 65507 - HEADER.size
"""The most air bytes one datagram carries (the IPv4 UDP payload limit less the header)."""
_QUERY_KEYS = ("peers", "bind", "iface", "ttl")


def pack_datagram(robot_id: int, tag: int, data: bytes) -> bytes:
    """The datagram carrying `data` from `robot_id`'s radio with instance tag `tag`."""
    return HEADER.pack(MAGIC, VERSION, 0, robot_id, tag) + bytes(data)


def unpack_datagram(datagram: bytes) -> tuple[int, int, bytes] | None:
    """(robot id, instance tag, air bytes) of one of our datagrams; None if it is not one."""
    if len(datagram) <= HEADER.size:
        return None
    magic, version, _flags, robot, tag = HEADER.unpack_from(datagram)
    if magic != MAGIC or version != VERSION:
        return None
    return robot, tag, datagram[HEADER.size :]


class UdpRadio:
    """A `RadioLink` over a non-blocking UDP socket: broadcast, multicast or a peer list."""

    def __init__(
        self,
        robot_id: int,
        *,
        port: int = DEFAULT_PORT,
        group: str = LOOPBACK_BROADCAST,
        bind: str | None = None,
        peers: Sequence[tuple[str, int]] = (),
        iface: str | None = None,
        ttl: int = 1,
        max_per_poll: int = 1024,
    ) -> None:
        if isinstance(robot_id, bool) or not isinstance(robot_id, int):
            raise ValueError(f"robot id must be an int, got {robot_id!r}")
        if not 0 <= robot_id <= 0xFFFF:
            raise ValueError(f"robot id must be in 0..65535, got {robot_id}")
        if not 0 < port < 65536:
            raise ValueError(f"port must be 1..65535, got {port}")
        self.robot_id = robot_id
        self.stats: Counter[str] = Counter()
        self.max_per_poll = max_per_poll
        # Random so that two radios given the same id (a misconfiguration) are told apart.
        self.tag = random.SystemRandom().getrandbits(32)
        if group == "localhost":
            group = LOOPBACK_BROADCAST
        address = ipaddress.IPv4Address(group)
        multicast = address.is_multicast
        if bind is None:
            bind = "0.0.0.0" if multicast else group
        if peers:
            self.destinations = [(h, p) for h, p in peers]
        elif address.is_unspecified:
            self.destinations = [("255.255.255.255", port)]
        else:
            self.destinations = [(group, port)]
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            if multicast:
                local = socket.inet_aton(iface or "0.0.0.0")
                mreq = socket.inet_aton(group) + local
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
                if iface:
                    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, local)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            sock.bind((bind, port))
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self._sock: socket.socket | None = sock
        self.port = port
        self.group = group

    @classmethod
    def from_url(cls, url: str, robot_id: int, **kwargs: Any) -> UdpRadio:
        """A UdpRadio from `udp://HOST:PORT[?peers=H:P,...&bind=A&iface=A&ttl=N]` (module doc)."""
        parts = urlsplit(url)
        if parts.scheme != "udp":
            raise ValueError(f"not a udp:// URL: {url!r}")
        try:
            port = parts.port or DEFAULT_PORT
        except ValueError:
            raise ValueError(f"bad port in {url!r}") from None
        host = parts.hostname or "0.0.0.0"
        query = dict(parse_qsl(parts.query, keep_blank_values=True))
        extra = set(query) - set(_QUERY_KEYS)
        if extra:
            raise ValueError(f"unknown query keys {sorted(extra)} in {url!r}")
        if "peers" in query:
            peers = []
            for item in query["peers"].split(","):
                h, _, p = item.strip().partition(":")
                try:
                    peers.append((h, int(p) if p else port))
                except ValueError:
                    raise ValueError(f"bad peer {item!r} in {url!r}") from None
            kwargs["peers"] = peers
        if "bind" in query:
            kwargs["bind"] = query["bind"]
        if "iface" in query:
            kwargs["iface"] = query["iface"]
        if "ttl" in query:
            try:
                kwargs["ttl"] = int(query["ttl"])
            except ValueError:
                raise ValueError(f"bad ttl in {url!r}") from None
        return cls(robot_id, port=port, group=host, **kwargs)

    @property
    def address(self) -> tuple[str, int]:
        """The bound (host, port)."""
        if self._sock is None:
            raise ValueError("radio is closed")
        host, port = self._sock.getsockname()[:2]
        return host, port

    def fileno(self) -> int:
        """The socket's file descriptor, for a select() loop."""
        if self._sock is None:
            raise ValueError("radio is closed")
        return self._sock.fileno()

    def send(self, data: bytes) -> None:
        """Broadcast one bundle's air bytes (ValueError if empty or too long for a datagram)."""
        if self._sock is None:
            raise ValueError("radio is closed")
        if not 0 < len(data) <= MAX_DATA:
            raise ValueError(f"{len(data)} bytes: a datagram carries 1..{MAX_DATA}")
        datagram = pack_datagram(self.robot_id, self.tag, data)
        for dest in self.destinations:
            try:
                self._sock.sendto(datagram, dest)
            except BlockingIOError:
                self.stats["dropped_out"] += 1  # the socket buffer is full: a lost frame
            except OSError:
                self.stats["io_errors"] += 1
            else:
                self.stats["datagrams_out"] += 1
                self.stats["bytes_out"] += len(datagram)

    def poll(self) -> list[tuple[int, bytes]]:
        """(sender robot id, air bytes) of the datagrams received since the last poll."""
        sock = self._sock
        if sock is None:
            return []
        out = []
        for _ in range(self.max_per_poll):
            try:
                datagram = sock.recv(65536)
            except BlockingIOError:
                break
            except OSError:
                # e.g. ICMP port-unreachable reported for an earlier unicast to a peer
                self.stats["io_errors"] += 1
                continue
            got = self._parse(datagram)
            if got is not None:
                out.append(got)
        return out

    def _parse(self, datagram: bytes) -> tuple[int, bytes] | None:
        self.stats["datagrams_in"] += 1
        self.stats["bytes_in"] += len(datagram)
        got = unpack_datagram(datagram)
        if got is None:
            self.stats["bad_datagrams"] += 1
            return None
        robot, tag, data = got
        if robot == self.robot_id:
            self.stats["echoes" if tag == self.tag else "id_conflicts"] += 1
            return None
        self.stats["delivered"] += 1
        return robot, data

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> UdpRadio:
        """The radio itself."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the radio."""
        self.close()
