"""UdpRadio: several radios on this machine hear each other, and nothing else."""

from __future__ import annotations

import select
import socket
import struct
import time
from collections.abc import Callable, Iterator

import pytest

from fieldkit.radio import RadioLink, UdpRadio, from_profile, open_radio
from fieldkit.radio import udp as U
from fieldkit.robot import bundle as B
from fieldkit.robot.profiles import RadioSettings


def free_port() -> int:
    """A UDP port nobody on this machine is bound to right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def air(robot: int, number: int) -> bytes:
    """One bundle's air bytes."""
    return B.encode(B.Bundle(robot, (b"msg",), 45.0, -73.0, 1.0, number=number))


def collect(
    radios: list[UdpRadio], until: Callable[[dict[int, list[tuple[int, bytes]]]], bool]
) -> dict[int, list[tuple[int, bytes]]]:
    """Poll until `until(received)` holds, waiting on the sockets (10 s deadline)."""
    got: dict[int, list[tuple[int, bytes]]] = {r.robot_id: [] for r in radios}
    deadline = time.monotonic() + 10
    while not until(got):
        assert time.monotonic() < deadline, {r.robot_id: dict(r.stats) for r in radios}
        select.select([r.fileno() for r in radios], [], [], 0.05)
        for r in radios:
            got[r.robot_id] += r.poll()
    return got


@pytest.fixture
def radios() -> Iterator[list[UdpRadio]]:
    """A list the test fills with radios; all closed afterwards."""
    made: list[UdpRadio] = []
    yield made
    for r in made:
        r.close()


def test_three_radios_on_loopback(radios: list[UdpRadio]) -> None:
    """Each hears both others, once each, never itself (its echoes are counted)."""
    port = free_port()
    radios += [UdpRadio(i, port=port) for i in (1, 2, 3)]
    assert all(isinstance(r, RadioLink) for r in radios)
    for r in radios:
        r.send(air(r.robot_id, 1))
    got = collect(radios, lambda g: all(len(v) == 2 for v in g.values()))
    for r in radios:
        others = sorted(got[r.robot_id])
        assert others == sorted((i, air(i, 1)) for i in (1, 2, 3) if i != r.robot_id)
    # the echoes arrive with the rest: wait until each radio has seen its own
    collect(radios, lambda g: all(r.stats["echoes"] == 1 for r in radios))
    assert all(r.stats["datagrams_out"] == 1 and r.stats["delivered"] == 2 for r in radios)


def test_bad_datagrams_and_id_conflicts_are_counted(radios: list[UdpRadio]) -> None:
    """Short, wrong magic or version, empty: counted; another radio with our id: dropped."""
    port = free_port()
    radios += [UdpRadio(1, port=port), UdpRadio(1, port=port)]
    a, twin = radios
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    good_head = struct.pack(">2sBBHI", b"FK", 1, 0, 5, 1234)
    for datagram in (
        b"",
        b"FK",
        good_head,  # no data
        b"XX" + good_head[2:] + b"data",
        good_head[:2] + b"\x02" + good_head[3:] + b"data",
    ):
        raw.sendto(datagram, (U.LOOPBACK_BROADCAST, port))
    raw.sendto(good_head + b"valid", (U.LOOPBACK_BROADCAST, port))
    raw.close()
    got = collect([a], lambda g: bool(g[1]))
    assert got[1] == [(5, b"valid")]
    collect([a], lambda g: a.stats["bad_datagrams"] == 5)
    twin.send(air(1, 1))
    collect([a], lambda g: a.stats["id_conflicts"] == 1)
    assert a.stats["delivered"] == 1


def test_flags_byte_is_ignored(radios: list[UdpRadio]) -> None:
    """Room for later versions: a nonzero flags byte does not make a datagram bad."""
    port = free_port()
    radios.append(UdpRadio(1, port=port))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
        raw.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        raw.sendto(struct.pack(">2sBBHI", b"FK", 1, 0xFF, 2, 7) + b"x", ("127.255.255.255", port))
    assert collect(radios, lambda g: bool(g[1]))[1] == [(2, b"x")]


def test_peer_list_unicast(radios: list[UdpRadio]) -> None:
    """?peers=: datagrams go to the listed addresses only."""
    pa, pb, pc = free_port(), free_port(), free_port()
    a = UdpRadio.from_url(f"udp://127.0.0.1:{pa}?peers=127.0.0.1:{pb}", 1)
    b = UdpRadio.from_url(f"udp://127.0.0.1:{pb}?peers=127.0.0.1:{pa},127.0.0.1:{pc}", 2)
    c = UdpRadio.from_url(f"udp://127.0.0.1:{pc}?peers=127.0.0.1:{pb}", 3)
    radios += [a, b, c]
    assert a.destinations == [("127.0.0.1", pb)]
    a.send(air(1, 1))
    b.send(air(2, 1))
    got = collect(radios, lambda g: bool(g[1] and g[2] and g[3]))
    assert got == {1: [(2, air(2, 1))], 2: [(1, air(1, 1))], 3: [(2, air(2, 1))]}


def test_multicast_on_loopback(radios: list[UdpRadio]) -> None:
    """udp://239.x.x.x:port?iface=127.0.0.1 : a multicast group on this machine."""
    port = free_port()
    url = f"udp://239.255.77.1:{port}?iface=127.0.0.1&ttl=0"
    try:
        radios += [open_radio(url, 1), open_radio(url, 2)]  # type: ignore[list-item]
    except OSError as e:  # a kernel without multicast on lo
        pytest.skip(f"no multicast here: {e}")
    radios[0].send(air(1, 3))
    assert collect(radios, lambda g: bool(g[2]))[2] == [(1, air(1, 3))]


def test_url_forms_and_errors() -> None:
    """Defaults per address kind; bad URLs raise ValueError."""
    port = free_port()
    with UdpRadio.from_url(f"udp://localhost:{port}", 1) as r:
        assert r.destinations == [(U.LOOPBACK_BROADCAST, port)]
        assert r.address == (U.LOOPBACK_BROADCAST, port)
    with UdpRadio.from_url(f"udp://0.0.0.0:{port}", 1) as r:
        assert r.destinations == [("255.255.255.255", port)] and r.address[0] == "0.0.0.0"
    with UdpRadio.from_url(f"udp://0.0.0.0:{port}?peers=10.0.0.2,10.0.0.3:99", 1) as r:
        assert r.destinations == [("10.0.0.2", port), ("10.0.0.3", 99)]
    for bad in (
        f"tcp://127.0.0.1:{port}",
        f"udp://127.0.0.1:{port}?color=red",
        f"udp://127.0.0.1:{port}?ttl=x",
        f"udp://127.0.0.1:{port}?peers=h:p",
        "udp://127.0.0.1:99999",
    ):
        with pytest.raises(ValueError):
            UdpRadio.from_url(bad, 1)
    with pytest.raises(ValueError):
        UdpRadio(70000, port=port)


def test_send_limits_and_closed_radio() -> None:
    """Empty or oversize sends raise; a closed radio polls nothing and refuses sends."""
    r = UdpRadio(1, port=free_port())
    with pytest.raises(ValueError):
        r.send(b"")
    with pytest.raises(ValueError):
        r.send(bytes(U.MAX_DATA + 1))
    r.close()
    assert r.poll() == []
    with pytest.raises(ValueError):
        r.send(b"x")


def test_unreachable_destination_is_counted() -> None:
    """A send that the network refuses moves io_errors; it does not raise."""
    with UdpRadio(1, port=free_port(), peers=[("255.255.255.255", 0)]) as r:  # port 0: EINVAL
        r.send(b"x")
        assert r.stats["io_errors"] == 1 and r.stats["datagrams_out"] == 0


def test_from_profile_udp() -> None:
    """kind = "udp": the profile's port, broadcast on every interface."""
    port = free_port()
    r = from_profile(RadioSettings("udp", "", 230400, 1, port, 190), 4)
    assert isinstance(r, UdpRadio) and r.port == port
    assert r.destinations == [("255.255.255.255", port)]
    r.close()


def test_datagram_format_without_a_socket() -> None:
    """The 10-byte header: magic, version, flags, robot id, tag; anything else is not ours."""
    datagram = U.pack_datagram(0x0102, 0xDEADBEEF, b"air")
    assert datagram == b"FK\x01\x00\x01\x02\xde\xad\xbe\xef" + b"air"
    assert U.unpack_datagram(datagram) == (0x0102, 0xDEADBEEF, b"air")
    assert U.unpack_datagram(datagram[:10]) is None  # a header and no air bytes
    assert U.unpack_datagram(b"FX" + datagram[2:]) is None
    assert U.unpack_datagram(datagram[:2] + b"\x02" + datagram[3:]) is None
    assert U.unpack_datagram(datagram[:3] + b"\x07" + datagram[4:]) == (0x0102, 0xDEADBEEF, b"air")
