"""`XBeeRadio`: the XBee radio on a serial port, a thin pyserial shell around `XBeeCore`.

Everything the protocol decides (de-framing, sender ids, XbeeMav's packets, acks and pacing)
is `fieldkit.radio.xbee_core.XBeeCore`'s. This module only moves bytes: it opens the port
(non-blocking), reads what the operating system holds, writes the core's frames when the port
has room, and reopens a port it opened after an I/O error. It reads the clock once per call
and feeds that time to the core.

A device that goes away (the XBee's USB cable worked loose: EIO, the node file gone) never
raises into the node's loop. The port is closed, `radio: /dev/xbee lost (...); reopening` is
logged once, the frames the core releases while it is gone are dropped and counted
(`frames_dropped_down`: the radio is lossy anyway, and XbeeMav's own acks and pings repair
what matters), and the same path is tried once every `reopen_interval_s` of the radio's
clock. When it opens again (the udev symlink pointing at the module's new ttyUSBn), the
core forgets any half frame and `radio: /dev/xbee back after N s` is logged once.
"""

from __future__ import annotations

import logging
import os
import select
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit

import serial

from .base import IdTable, UnknownSenders
from .xbee import XBEEMAV_DEST16, FrameReader
from .xbee_core import PacketReceived, XBeeCore
from .xbeemav import DEFAULT_BAUD, XbeeMav

_OUR_PARAMS = ("baud", "api", "unknown")

_log = logging.getLogger("fieldkit.radio")


@dataclass(frozen=True)
class XBeeUrl:
    """Where a radio URL's XBee is: a device path or a pyserial URL (exactly one), and the
    `XBeeRadio` options its query gives (`baud`, `api_mode`, `unknown`)."""

    device: str | None
    pyserial_url: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)


def parse_url(url: str) -> XBeeUrl:
    """Read `serial:///dev/ttyUSB0?baud=230400&api=1`, a device path or a pyserial URL
    (`loop://...`, its own query keys kept); ValueError names what does not parse."""
    parts = urlsplit(url)
    if not parts.scheme or len(parts.scheme) == 1:  # "/dev/ttyUSB0", "COM3", "C:\\..."
        return XBeeUrl(url)
    query = parse_qsl(parts.query, keep_blank_values=True)
    ours = {k: v for k, v in query if k in _OUR_PARAMS}
    theirs = [(k, v) for k, v in query if k not in _OUR_PARAMS]
    options: dict[str, Any] = {}
    try:
        if "baud" in ours:
            options["baud"] = int(ours["baud"])
        if "api" in ours:
            options["api_mode"] = int(ours["api"])
    except ValueError:
        raise ValueError(f"bad baud or api in {url!r}") from None
    if "unknown" in ours:
        options["unknown"] = ours["unknown"]
    if parts.scheme == "serial":
        if theirs:
            raise ValueError(f"unknown query keys {[k for k, _ in theirs]} in {url!r}")
        path = parts.netloc + parts.path
        if not path:
            raise ValueError(f"no device in {url!r}")
        return XBeeUrl(path, options=options)
    # Any other scheme is one of pyserial's URL handlers, given its own query keys. Their
    # writes block (loop:// refuses every write with write_timeout=0): tests and bridges.
    inner = f"{parts.scheme}://{parts.netloc}{parts.path}"
    if theirs:
        inner += "?" + urlencode(theirs)
    return XBeeUrl(None, inner, options)


class XBeeRadio:
    """A `RadioLink` over an XBee in API mode on a serial port, speaking XbeeMav's packets.

    `port` is a device path (opened at `baud`, non-blocking) or an open pyserial port (e.g.
    `serial.serial_for_url("loop://")`). `robot_id` (0..255) is this node's sysid and
    address; `id_map` maps XBee serials (16 hex digits) to robot ids; `unknown` says what to
    do with frames from other serials (see `fieldkit.radio.base`). `send` derives msgid from
    a BUZZ_MESSAGE's message number as ROSBuzz does (so `send(encode(bundle))` writes the
    docs/bundle.md#worked-example frame), otherwise from a counter of its own. Engine options
    (`interframe_s`, `round_wait_s`, ...) go to `XbeeMav`.

    `stats` counts, besides the `XBeeCore`, `FrameReader` and `XbeeMav` counters: bytes_out,
    frames_out, io_errors (reads and writes that failed), reopens, reopen_failures (attempts
    while the device was gone), frames_dropped_down (frames released while it was gone),
    tx_overflow (frames dropped because the port would not drain). A device path that fails
    is tried again every `reopen_interval_s` seconds of `clock`.
    """

    def __init__(
        self,
        port: serial.SerialBase | str,
        robot_id: int,
        *,
        baud: int = DEFAULT_BAUD,
        api_mode: int = 1,
        id_map: IdTable | Mapping[str, int] | Mapping[int, int] | None = None,
        unknown: str = "drop",
        clock: Callable[[], float] = time.monotonic,
        frame_id: int = 1,
        dest16: int = XBEEMAV_DEST16,
        idle_flush_s: float = 0.1,
        max_tx_buffer: int = 1 << 16,
        reopen_interval_s: float = 1.0,
        **engine_options: Any,
    ) -> None:
        self.core = XBeeCore(
            robot_id,
            api_mode=api_mode,
            id_map=id_map,
            unknown=unknown,
            frame_id=frame_id,
            dest16=dest16,
            idle_flush_s=idle_flush_s,
            now=clock(),
            **engine_options,
        )
        self.clock = clock
        self.max_tx_buffer = max_tx_buffer
        self.stats: Counter[str] = self.core.stats
        self._path = port if isinstance(port, str) else None
        self._baud = baud
        self._port: serial.SerialBase | None = None
        self.reopen_interval_s = reopen_interval_s
        self._reopen_at = 0.0
        self._down_since: float | None = None  # when the device was lost, while it is gone
        self._dropped_before = 0  # frames_dropped_down when it was lost
        #: Times the device was lost, and seconds it was down in the outages that ended.
        self.outages = 0
        self.down_s = 0.0
        self._tx = bytearray()
        self._closed = False
        if isinstance(port, str):
            self._port = self._open(port, baud)
        else:
            self._port = port

    # The core's settings, read where the radio's callers have always found them.

    @property
    def robot_id(self) -> int:
        """This node's robot id (its sysid and XbeeMav address)."""
        return self.core.robot_id

    @property
    def api_mode(self) -> int:
        """The XBee API mode: 1 (XbeeMav's, unescaped) or 2 (escaped)."""
        return self.core.api_mode

    @property
    def unknown(self) -> UnknownSenders:
        """What happens to frames from serials missing from the id table."""
        return self.core.unknown

    @property
    def ids(self) -> IdTable:
        """XBee serial -> robot id."""
        return self.core.ids

    @property
    def reader(self) -> FrameReader:
        """The core's de-framer."""
        return self.core.reader

    @property
    def engine(self) -> XbeeMav:
        """The core's XbeeMav packet engine."""
        return self.core.engine

    @staticmethod
    def _open(path: str, baud: int) -> serial.SerialBase:
        return serial.Serial(path, baud, timeout=0, write_timeout=0)

    @classmethod
    def from_url(cls, url: str, robot_id: int, **kwargs: Any) -> XBeeRadio:
        """An XBeeRadio from `serial:///dev/ttyUSB0?baud=230400&api=1`, a path or a pyserial URL.

        A pyserial URL (`loop://`, `socket://host:port`, `spy://...`) takes the same query
        keys and is opened with blocking writes, for tests and bridges. Query keys: baud, api
        (1 or 2), unknown (drop or sysid); they override `kwargs`.
        """
        where = parse_url(url)
        kwargs.update(where.options)
        if where.device is not None:
            return cls(where.device, robot_id, **kwargs)
        assert where.pyserial_url is not None
        port = serial.serial_for_url(
            where.pyserial_url, kwargs.get("baud", DEFAULT_BAUD), timeout=0
        )
        return cls(port, robot_id, **kwargs)

    # ------------------------------------------------------------------ RadioLink

    def send(self, data: bytes) -> None:
        """Queue one bundle's air bytes (whole 8-byte words) for broadcast; writes if due."""
        if self._closed:
            raise ValueError("radio is closed")
        self.core.submit(data)
        self._pump(self.clock())

    def poll(self) -> list[tuple[int, bytes]]:
        """(sender id, payload) received since the last poll; also writes the frames now due."""
        if self._closed:
            return []
        now = self.clock()
        events = self.core.receive_data(self._read(now), now)
        out = [(e.sender, e.data) for e in events if isinstance(e, PacketReceived)]
        self._pump(now)
        return out

    def fileno(self) -> int | None:
        """The port's file descriptor, for a select() loop (None for ports without one)."""
        try:
            return None if self._port is None else self._port.fileno()
        except (AttributeError, NotImplementedError, OSError, serial.SerialException):
            return None

    def close(self) -> None:
        """Close the port (if this radio opened it or was given it)."""
        self._closed = True
        if self._port is not None:
            try:
                self._port.close()
            except (OSError, serial.SerialException):
                pass
            self._port = None

    def __enter__(self) -> XBeeRadio:
        """The radio itself."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the radio."""
        self.close()

    # ------------------------------------------------------------------ the port

    @property
    def down(self) -> bool:
        """Whether the device this radio opened is lost and not reopened yet."""
        return self._down_since is not None

    def down_for(self, now: float | None = None) -> float:
        """Seconds the device has been down at `now` (the radio's clock; 0 while it is up)."""
        since = self._down_since
        if since is None:
            return 0.0
        return max(0.0, (self.clock() if now is None else now) - since)

    def _pump(self, now: float) -> None:
        for frame in self.core.frames_to_send(now):
            if self._down_since is not None:
                self.stats["frames_dropped_down"] += 1
                continue
            if len(self._tx) + len(frame) > self.max_tx_buffer:
                self.stats["tx_overflow"] += 1
                continue
            self._tx += frame
            self.stats["frames_out"] += 1
        self._write()

    def _port_ready(self, now: float) -> serial.SerialBase | None:
        if (
            self._port is None
            and self._path is not None
            and not self._closed
            and now >= self._reopen_at
        ):
            self._reopen_at = now + self.reopen_interval_s
            try:
                self._port = self._open(self._path, self._baud)
            except (OSError, serial.SerialException):
                self.stats["reopen_failures"] += 1  # still gone: one open() a second
                return None
            self.core.reset()  # the rest of a half frame from before never comes
            self.stats["reopens"] += 1
            if self._down_since is not None:
                down = max(0.0, now - self._down_since)
                self._down_since = None
                self.down_s += down
                # A warning like the loss it ends: the node shows fieldkit's library loggers
                # from warnings up, and the pair brackets the outage in the log.
                _log.warning(
                    "radio: %s back after %g s (%d frames dropped meanwhile)",
                    self._path,
                    round(down, 1),
                    self.stats["frames_dropped_down"] - self._dropped_before,
                )
        return self._port

    def _io_failed(self, now: float, what: str, e: BaseException) -> None:
        self.stats["io_errors"] += 1
        if self._path is None:
            return  # not ours to reopen: keep counting
        try:
            if self._port is not None:
                self._port.close()
        except (OSError, serial.SerialException):
            pass
        self._port = None
        self._tx.clear()  # a frame cut short: the module would take its rest as garbage
        # The first attempt a whole interval later: a device on its way out can still open.
        self._reopen_at = now + self.reopen_interval_s
        if self._down_since is None:
            self._down_since = now
            self.outages += 1
            self._dropped_before = self.stats["frames_dropped_down"]
            _log.warning("radio: %s lost (%s); reopening", self._path, _reason(what, e))

    def _read(self, now: float) -> bytes:
        port = self._port_ready(now)
        if port is None:
            return b""
        chunks = []
        try:
            for _ in range(16):  # at most 64 KiB per poll: stay non-blocking under a flood
                chunk = port.read(4096)
                if not chunk:
                    break
                chunks.append(chunk)
                if len(chunk) < 4096:
                    break
        except (OSError, serial.SerialException) as e:
            self._io_failed(now, "read failed", e)
        return b"".join(chunks)

    def _write(self) -> None:
        port = self._port
        if port is None or not self._tx:
            return
        try:
            fd = port.fileno() if hasattr(port, "fileno") else None
        except (OSError, serial.SerialException, AttributeError, NotImplementedError):
            fd = None
        try:
            while self._tx:
                # pyserial's non-blocking write spins on EAGAIN: write only when there is room.
                if fd is not None and not select.select([], [fd], [], 0)[1]:
                    break
                n = port.write(bytes(self._tx[:4096]))
                if not n:
                    break
                del self._tx[:n]
                self.stats["bytes_out"] += n
        except (OSError, serial.SerialException) as e:
            self._io_failed(self.clock(), "write failed", e)


def _reason(what: str, e: BaseException) -> str:
    """Why the port failed, short: "read failed: Input/output error".

    pyserial wraps the OS error in text of its own, and reports a tty at end of file (the
    USB device went away) as "device reports readiness to read but returned no data ...".
    """
    for err in (e, e.__cause__ or e.__context__):
        if isinstance(err, OSError) and isinstance(err.errno, int) and err.errno > 0:
            return f"{what}: {os.strerror(err.errno)}"
    if "returned no data" in str(e):
        return f"{what}: end of file, device disconnected"
    return f"{what}: {e}"
