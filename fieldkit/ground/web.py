"""The ground station's page on localhost: static files, the swarm view as JSON and as a
Server-Sent Events stream, and the command endpoint.

The standard library's `ThreadingHTTPServer`: one thread per connection, so two browsers,
or a browser that reconnects, each get their own stream; a browser that goes away ends its
thread at the next write (a broken pipe, caught). The stream sends the newest view at
`rate_hz` and never queues: a slow page gets fewer, never older, views. The page's files are
package data (`fieldkit/ground/static/`): nothing comes from the internet.

    GET  /                 the page (static/index.html)
    GET  /static/NAME      its script and style
    GET  /api/state        the view, once (JSON)
    GET  /api/stream       the view, `rate_hz` times a second (text/event-stream)
    POST /api/command      {"code": 22, "params": [], "to": null} -> {"seq": ...} or
                           400 {"error": "..."}
"""

from __future__ import annotations

import json
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any

from fieldkit.ground.core import CODES, GroundError, GroundStation

#: How often the stream sends the view (the issue asks for at least 2 Hz).
STREAM_HZ = 4.0
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript", ".css": "text/css"}
_MAX_BODY = 4096


def static_file(name: str) -> bytes | None:
    """A file of the page (package data), or None if there is no such file."""
    if "/" in name or name.startswith("."):
        return None
    f = resources.files("fieldkit.ground").joinpath("static", name)
    try:
        return f.read_bytes()
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        return None


class _ViewCache:
    """The view as JSON, made at most once per interval whatever the number of pages."""

    def __init__(self, station: GroundStation, interval: float) -> None:
        self.station = station
        self.interval = interval
        self.lock = threading.Lock()
        self.made = 0.0
        self.data = b""

    def get(self) -> bytes:
        with self.lock:
            now = time.monotonic()
            if not self.data or now - self.made >= self.interval:
                self.data = json.dumps(self.station.snapshot(), separators=(",", ":")).encode()
                self.made = now
            return self.data


class GroundServer(ThreadingHTTPServer):
    """The page's HTTP server for one ground station."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(
        self,
        station: GroundStation,
        host: str = "127.0.0.1",
        port: int = 8080,
        *,
        rate_hz: float = STREAM_HZ,
    ) -> None:
        self.station = station
        self.rate_hz = rate_hz
        self.cache = _ViewCache(station, 1.0 / rate_hz / 2)
        self.stopping = threading.Event()
        self.streams = 0
        super().__init__((host, port), _Handler)

    @property
    def url(self) -> str:
        """http://HOST:PORT/ of the page."""
        host, port = self.server_address[:2]
        return f"http://{host!s}:{port}/"

    def start(self) -> threading.Thread:
        """Serve in a background thread."""
        t = threading.Thread(target=self.serve_forever, name="ground-http", daemon=True)
        t.start()
        return t

    def stop(self) -> None:
        """Stop serving and end the streams."""
        self.stopping.set()
        self.shutdown()
        self.server_close()


class _Handler(BaseHTTPRequestHandler):
    server: GroundServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
        """Quiet: the page polls and streams; errors go to the event log instead."""

    def _send(self, status: int, body: bytes, ctype: str = "application/json") -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _error(self, status: int, text: str) -> None:
        self._send(status, json.dumps({"error": text}).encode())

    def do_GET(self) -> None:
        """The page, its files, the view and its stream."""
        path = self.path.split("?", 1)[0]
        try:
            if path in ("/", "/index.html"):
                body = static_file("index.html")
                assert body is not None
                self._send(200, body, _TYPES[".html"])
            elif path.startswith("/static/"):
                name = path[len("/static/") :]
                body = static_file(name)
                if body is None:
                    self._error(404, f"no file {name!r}")
                    return
                ext = name[name.rfind(".") :]
                self._send(200, body, _TYPES.get(ext, "application/octet-stream"))
            elif path == "/api/state":
                self._send(200, self.server.cache.get())
            elif path == "/api/stream":
                self._stream()
            elif path == "/api/codes":
                self._send(200, json.dumps(CODES).encode())
            else:
                self._error(404, f"no page {path!r}")
        except (BrokenPipeError, ConnectionResetError):
            pass  # the browser went away

    def _stream(self) -> None:
        server = self.server
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        period = 1.0 / server.rate_hz
        server.streams += 1
        try:
            while not server.stopping.is_set():
                self.wfile.write(b"data: " + server.cache.get() + b"\n\n")
                self.wfile.flush()
                if server.stopping.wait(period):
                    break
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass  # the browser closed the page or reconnects: it opens a new stream
        finally:
            server.streams -= 1

    def do_POST(self) -> None:
        """A command from the page."""
        path = self.path.split("?", 1)[0]
        if path != "/api/command":
            self._error(404, f"no endpoint {path!r}")
            return
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            length = -1
        if not 0 < length <= _MAX_BODY:
            self._error(400, f"a command is a JSON body of 1..{_MAX_BODY} bytes")
            return
        try:
            body = json.loads(self.rfile.read(length))
            code, params, to = _parse_command(body)
            c = self.server.station.command(code, params, to)
        except (ValueError, GroundError) as e:  # json.JSONDecodeError is a ValueError
            self._error(HTTPStatus.BAD_REQUEST, str(e))
            return
        self._send(200, json.dumps({"seq": c.seq, "text": c.describe()}).encode())


def _parse_command(body: object) -> tuple[int, list[float], int | None]:
    """(code, params, robot or None) of a command's JSON; ValueError saying what is wrong."""
    if not isinstance(body, dict):
        raise ValueError("a command is a JSON object {code, params, to}")
    code = body.get("code")
    if isinstance(code, str):
        if code not in CODES:
            raise ValueError(f"unknown command {code!r}: one of {', '.join(CODES)} or a number")
        code = CODES[code]
    if isinstance(code, bool) or not isinstance(code, int):
        raise ValueError(f"code {code!r}: a command name or an integer")
    params = body.get("params") or []
    if not isinstance(params, list) or not all(
        isinstance(p, int | float) and not isinstance(p, bool) for p in params
    ):
        raise ValueError("params: a list of numbers")
    to = body.get("to")
    if to is not None and (isinstance(to, bool) or not isinstance(to, int)):
        raise ValueError(f"to {to!r}: a robot id, or null for every robot")
    return code, [float(p) for p in params], to


__all__ = ["GroundServer", "STREAM_HZ", "static_file"]
