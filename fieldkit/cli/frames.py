"""`fieldkit frames decode`: the protocol inspector (fieldkit.frames) on the command line."""

from __future__ import annotations

import json
import os
import re
import sys
from collections.abc import Callable, Iterator
from typing import Annotated, Any

import typer

from fieldkit import frames as registry
from fieldkit.cli.errors import fail, usage_error
from fieldkit.errors import FrameError

app = typer.Typer(
    help="Protocol inspector: decode frames of the byte formats fieldkit speaks.",
    no_args_is_help=True,
)

#: What may separate hex digits inside one frame argument.
_SEPARATORS = re.compile(r"[\s:]+")
#: Where --app-key may come from instead, so that a real key stays off the command line.
APP_KEY_ENV = "FIELDKIT_DJI_APP_KEY"
#: How much of stdin one read takes at most (a read returns what a pipe has so far).
_READ_SIZE = 1 << 16


def _frame_bytes(index: int, text: str, protocol: registry.Protocol) -> bytes:
    """The bytes of frame argument `index` (1-based): hex, or text where the protocol allows."""
    digits = _SEPARATORS.sub("", text)
    try:
        data = bytes.fromhex(digits)
    except ValueError:
        if protocol.text:
            return os.fsencode(text)  # the bytes the shell passed, whatever they are
        raise usage_error(
            f"frame {index}: {text[:40]!r} is not hex (pairs of hex digits; spaces and colons "
            "may separate them)"
        ) from None
    if not data:
        raise usage_error(f"frame {index} is empty")
    return data


def _app_key(text: str | None, found: registry.Protocol) -> bytes | None:
    """The key bytes of --app-key, else of $FIELDKIT_DJI_APP_KEY for a protocol that takes
    one; an error that never repeats the key (exit 2 for the option, 1 for the variable)."""
    if text is None and found.app_key:
        env = os.environ.get(APP_KEY_ENV)
        if env:
            return _parse_key(env, APP_KEY_ENV, fail)
    return None if text is None else _parse_key(text, "--app-key", usage_error)


def _parse_key(text: str, given: str, error: Callable[[str], Exception]) -> bytes:
    from fieldkit.vehicle.dji.crypto import AppKeyError, parse_app_key

    try:
        return parse_app_key(text)
    except AppKeyError as e:
        raise error(f"{given}: {e}") from None


def _stdin_chunks() -> Iterator[bytes]:
    """stdin's bytes as they arrive (a serial port piped in shows frames as they come)."""
    stream = sys.stdin.buffer
    read = getattr(stream, "read1", stream.read)
    while chunk := read(_READ_SIZE):
        yield chunk


def _echo(described: dict[str, Any]) -> None:
    """One frame, one line of JSON on stdout."""
    typer.echo(json.dumps(described))


@app.command("decode")
def decode_cmd(
    protocol: Annotated[
        str,
        typer.Argument(
            help="The protocol: "
            + "; ".join(f"{p.name} ({p.summary})" for p in registry.PROTOCOLS.values())
            + "."
        ),
    ],
    frames: Annotated[
        list[str] | None,
        typer.Argument(
            help="Frames, one per argument, as hex digits (spaces and colons may separate "
            "them: 'fd 09 00 ...'); nmea also takes the sentence text.",
            show_default=False,
        ),
    ] = None,
    stdin: Annotated[
        bool,
        typer.Option(
            "--stdin",
            help="Instead of arguments, read a raw byte stream from stdin (a capture, a "
            "serial port) and decode every frame found in it, skipping noise; a summary "
            "line goes to stderr.",
        ),
    ] = False,
    api_mode: Annotated[
        int | None,
        typer.Option(
            "--api-mode",
            metavar="1|2",
            min=1,
            max=2,
            help="XBee API mode of xbee, xbeemav and bundle frames: 1 (unescaped, as "
            "XbeeMav radios run; the default) or 2 (escaped).",
            show_default=False,
        ),
    ] = None,
    app_key: Annotated[
        str | None,
        typer.Option(
            "--app-key",
            metavar="HEX",
            help="dji: the developer's app key (64 hex digits) that decrypts encrypted "
            f"frames; ${APP_KEY_ENV} keeps it out of shell history. Without it an encrypted "
            "frame shows its ciphertext.",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Decode frames of PROTOCOL: one JSON object per frame on stdout, its fields named as in
    the protocol's spec. A frame that fails its checksum or layout stops the command with
    `error: frame N: WHAT at byte K` (K counts from 0 at the frame's first byte)."""
    found = registry.PROTOCOLS.get(protocol)
    if found is None:
        raise usage_error(f"unknown protocol {protocol!r}: one of {', '.join(registry.names())}")
    if api_mode is not None and not found.api_mode:
        raise usage_error(f"--api-mode applies to XBee-framed protocols, not {protocol}")
    if app_key is not None and not found.app_key:
        raise usage_error(f"--app-key applies to dji frames, not {protocol}")
    if stdin == bool(frames):
        raise usage_error("give the frames as arguments, or --stdin for a byte stream (not both)")
    options = registry.Options(api_mode=api_mode or 1, app_key=_app_key(app_key, found))
    if stdin:
        _decode_stream(found, options)
        return
    data = [_frame_bytes(i, text, found) for i, text in enumerate(frames or [], 1)]
    for i, frame in enumerate(data, 1):
        try:
            described = found.describe(frame, options)
        except FrameError as e:
            raise fail(f"frame {i}: {e.what} at byte {e.offset}") from None
        _echo(described)


def _decode_stream(protocol: registry.Protocol, options: registry.Options) -> None:
    """--stdin: every frame found, then the summary; a failure only if none was found."""
    counts = registry.StreamCounts()
    try:
        for described in registry.decode_stream(protocol, _stdin_chunks(), options, counts):
            _echo(described)
    finally:
        typer.echo(counts.summary(), err=True)
    if counts.frames == 0:
        hint = " (another protocol, API mode or baud rate?)" if counts.bytes_in else ""
        raise fail(f"stdin: no {protocol.name} frame in {counts.bytes_in} bytes{hint}")
