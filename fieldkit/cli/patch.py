"""`fieldkit patch apply`: what a robot does with a received update, offline."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fieldkit.cli.errors import fail
from fieldkit.cli.output import wrote

app = typer.Typer(
    help="Signed, encrypted update patches (made by `fieldkit update --patch-out`).",
    no_args_is_help=True,
)

#: The file beside a .bo that records its version number (one integer, as text).


@app.command("apply")
def apply_cmd(
    patch: Annotated[Path, typer.Argument(help="The patch file.")],
    base: Annotated[Path, typer.Option("--base", help="The .bo the patch was made against.")],
    keys: Annotated[
        Path, typer.Option("--keys", help="Key directory with operator.pub and swarm.key.")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="The new .bo to write.")],
    current_version: Annotated[
        int | None,
        typer.Option(
            "--current-version",
            help="The version the base is (default: BASE.version beside it, else 0); "
            "a patch must be newer.",
        ),
    ] = None,
) -> None:
    """Verify, decrypt and apply PATCH to BASE as a robot would, and write the new version
    (OUTPUT, its .bdb and .bpos beside it, and OUTPUT.version); on any problem write nothing."""
    from fieldkit.update.keys import KeyFileError, load_robot_keys
    from fieldkit.update.patch import MAX_PATCH_BYTES, PatchError, open_update
    from fieldkit.update.release import Release, ReleaseError, read_version, write_version

    _check_output(output)  # before any work: a bad -o is a typing mistake, not the patch
    try:
        with patch.open("rb") as f:
            data = f.read(MAX_PATCH_BYTES + 1)  # a longer file is refused, never read whole
    except OSError as e:
        raise fail(f"{patch}: cannot read: {e.strerror or e}") from None
    try:
        old = Release.read(base)
        robot_keys = load_robot_keys(keys)
    except (KeyFileError, ReleaseError) as e:
        raise fail(e) from None
    try:
        hint = "it holds one integer; or give --current-version N"
        current = read_version(base, hint) if current_version is None else current_version
    except ReleaseError as e:
        raise fail(e) from None
    try:
        header, new = open_update(data, base=old, keys=robot_keys, current_version=current)
    except PatchError as e:
        raise fail(f"{patch}: rejected ({e.reason}): {e}") from None
    try:
        new.write(output)
        version_file = write_version(output, header.version)
    except OSError as e:
        raise fail(f"{e.filename or output}: cannot write: {e.strerror or e}") from None
    wrote(output)
    for suffix, side in ((".bdb", new.bdb), (".bpos", new.bpos)):
        if side:
            wrote(output.with_suffix(suffix))
    wrote(version_file)
    typer.echo(f"version {header.version} ({new.hash[:12]}), from {old.hash[:12]}")


def _check_output(output: Path) -> None:
    """Fail now if OUTPUT cannot be a file: a directory, or in a directory that is not one."""
    if output.is_dir():
        raise fail(f"-o {output}: is a directory")
    if not output.parent.is_dir():
        raise fail(f"-o {output}: {output.parent} is not a directory")


__all__ = ["app"]
