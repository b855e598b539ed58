"""`fieldkit update SCRIPT.bzz`: compile, test, sign and encrypt a new script version.

One run: compile the script (`-I` include directories), try it in the simulator on a small
swarm of each `--profile` (a script error refuses it), make the signed, encrypted patch
from the base release (`--base OLD.bo`, the version the swarm runs) and write it
(`--patch-out FILE`), with the new release beside it (FILE's stem `.bo`, `.bdb`, `.bpos`
and `.version`) for the next update to build on. `--watch` does that again on every save
of the script or of a file it includes, each new version building on the last one written.
"""

from __future__ import annotations

import signal
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

import bvm
from fieldkit.cli.errors import fail, report, usage_error
from fieldkit.cli.output import wrote
from fieldkit.errors import FieldkitError
from fieldkit.update.release import (
    SIDECARS,
    VERSION_SUFFIX,
    Release,
    ReleaseError,
    read_version,
    write_atomic,
    write_version,
)

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

#: The profiles a new version is tried on unless `--profile` says: the simulator's and the
#: node's default robot. A swarm of other robots names its own (`--profile husky`).
DEFAULT_PROFILES = ("solo",)

#: Files the new release is written as, beside the patch: never the patch's own name.
_RELEASE_SUFFIXES = (".bo", *SIDECARS, VERSION_SUFFIX)


@dataclass
class _Originator:
    """What every run of one `fieldkit update` shares, and the base the next builds on."""

    script: Path
    include_dirs: list[str]
    profiles: list[str]
    signing_key: Ed25519PrivateKey
    swarm_key: bytes
    patch_out: Path
    base: Release
    base_path: Path
    version: int

    def run(self) -> None:
        """Compile, test, patch, write: one new version (a FieldkitError or OSError says
        which step failed; nothing is written then)."""
        from fieldkit.sim.trial import DEFAULT_ROBOTS, DEFAULT_SECONDS, trial
        from fieldkit.update.pipeline import NothingToUpdate, build, make_patch_file

        profiles = self.profiles
        new = build(self.script, self.include_dirs, test=lambda p: trial(p, profiles))
        typer.echo(
            f"update: {self.script} compiled and passed its trial ({DEFAULT_ROBOTS} robots "
            f"of {', '.join(profiles)}, {DEFAULT_SECONDS:g} s simulated)",
            err=True,
        )
        try:
            data = make_patch_file(new, self.base, self.version, self.signing_key, self.swarm_key)
        except NothingToUpdate as e:
            raise NothingToUpdate(f"{self.script}: compiles to {self.base_path}: {e}") from None
        release = self.patch_out.with_suffix(".bo")
        # The new release and its number first: a patch on disk always has its base for
        # the next update beside it.
        new.write(release)
        for path in (release, *(release.with_suffix(s) for s in SIDECARS)):
            if path.exists():
                wrote(path)
        version_path = write_version(release, self.version)
        wrote(version_path)
        write_atomic(self.patch_out, data)
        wrote(self.patch_out)
        typer.echo(
            f"update: version {self.version} ({self.base.hash[:12]} -> {new.hash[:12]}), "
            f"patch of {len(data)} B in {self.patch_out}; the next update builds on {release}"
        )
        self.base, self.base_path, self.version = new, release, self.version + 1


def update_cmd(
    script: Annotated[
        Path | None, typer.Argument(help="The new version, a .bzz file.", show_default=False)
    ] = None,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    keys: Annotated[
        Path | None,
        typer.Option(
            "--keys",
            metavar="DIR",
            help="The operator's keys (`fieldkit keys init DIR`): operator.key, swarm.key.",
            show_default=False,
        ),
    ] = None,
    radio: Annotated[
        str | None,
        typer.Option(
            "--radio",
            metavar="URL",
            help="Send the update into a live swarm over this radio (as `fieldkit node`).",
            show_default=False,
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--patch-out",
            metavar="FILE",
            help="Write the patch to FILE, and the new release beside it (FILE's stem "
            ".bo/.bdb/.bpos/.version), the base of the next update.",
            show_default=False,
        ),
    ] = None,
    base: Annotated[
        Path | None,
        typer.Option(
            "--base",
            metavar="OLD.bo",
            help="The release the swarm runs (with its .bdb, .bpos and .version beside it); "
            "with --radio also the .bzz the robots were started with.",
            show_default=False,
        ),
    ] = None,
    version: Annotated[
        int | None,
        typer.Option(
            "--version",
            metavar="N",
            help="The new version's number (default: one more than OLD.version, 1 if none).",
            show_default=False,
        ),
    ] = None,
    watch: Annotated[
        bool,
        typer.Option(
            "--watch",
            help="Keep running: a new version on every save of the script or its "
            "includes (Ctrl-C stops).",
        ),
    ] = False,
    timeout: Annotated[
        float | None,
        typer.Option(
            "--timeout",
            metavar="S",
            help="With --radio: how long to wait for every robot to switch (default 600).",
            show_default=False,
        ),
    ] = None,
    profile: Annotated[
        list[str] | None,
        typer.Option(
            "--profile",
            help="A device profile the swarm has: the trial runs a small swarm of each "
            f"(repeatable; default {', '.join(DEFAULT_PROFILES)}).",
            show_default=False,
        ),
    ] = None,
    rollback: Annotated[
        bool,
        typer.Option("--rollback", help="Order the swarm back to its previous version."),
    ] = False,
) -> None:
    """Compile, test, sign and encrypt a new version of SCRIPT and write the patch
    (--patch-out) or send it to the swarm (--radio)."""
    if rollback:
        if script is not None or out is not None or base is not None or watch:
            raise usage_error("--rollback takes no SCRIPT, --patch-out, --base or --watch")
        if keys is None or radio is None:
            raise usage_error("--rollback needs --keys DIR and --radio URL")
        _rollback_over_radio(keys, radio, _timeout(timeout))
        return
    if script is None:
        raise usage_error("missing argument SCRIPT: the new version, a .bzz file")
    if keys is None:
        raise usage_error("missing option --keys DIR: the operator's keys (fieldkit keys init)")
    patch_out = out
    if (radio is None) == (patch_out is None):
        raise usage_error(
            "give one of --radio URL (send to a live swarm) or --patch-out FILE (write a file)"
        )
    if radio is not None:
        if watch:
            raise usage_error("--watch writes patch files (--patch-out); send each with --radio")
        _send_over_radio(script, include, keys, radio, base, version, profile, _timeout(timeout))
        return
    assert patch_out is not None
    if base is None:
        raise usage_error("--patch-out needs --base OLD.bo: the release the swarm runs now")
    if timeout is not None:
        raise usage_error("--timeout applies to --radio only")
    originator = _prepare(script, include, keys, patch_out, base, version, profile)
    if not watch:
        try:
            originator.run()
        except (FieldkitError, OSError) as e:
            raise fail(e) from None
        return
    _watch(originator)


def _prepare(
    script: Path,
    include: list[Path] | None,
    keys: Path,
    patch_out: Path,
    base: Path,
    version: int | None,
    profile: list[str] | None,
) -> _Originator:
    """Everything checked before the first run: a wrong key, base or profile fails at once."""
    from fieldkit.update.keys import load_robot_keys, load_signing_key

    if patch_out.suffix in _RELEASE_SUFFIXES:
        raise fail(
            f"--patch-out {patch_out}: the new release is written beside the patch as "
            f"{patch_out.with_suffix('.bo')} and its sidecars; give the patch another name, "
            f"such as {patch_out.with_suffix('.patch')}"
        )
    profiles = list(dict.fromkeys(profile or DEFAULT_PROFILES))
    _check_profiles(profiles)
    if not keys.is_dir():
        raise fail(
            f"--keys {keys}: no such directory\n  hint: `fieldkit keys init {keys}` creates "
            "the operator's keys"
        )
    try:
        signing_key = load_signing_key(keys)
        swarm_key = load_robot_keys(keys).swarm_key
        base_release = Release.read(base)
        base_release.program(str(base))  # a base that is not a program cannot be patched
    except (FieldkitError, bvm.BuzzLoadError) as e:
        raise fail(e, base) from None
    if version is None:
        try:
            version = read_version(base, "give the new version's number with --version N") + 1
        except ReleaseError as e:
            raise fail(e) from None
    elif version < 1:
        raise fail(f"--version {version}: a version number is 1 or more")
    return _Originator(
        script=script,
        include_dirs=[str(d) for d in include or []],
        profiles=profiles,
        signing_key=signing_key,
        swarm_key=swarm_key,
        patch_out=patch_out,
        base=base_release,
        base_path=base,
        version=version,
    )


#: How long `--radio` listens to the swarm before it sends (robots tell their version
#: once a second when nothing is happening).
LISTEN_S = 5.0

#: `--timeout` by default: time for a big, lossy swarm to pass a patch on and agree.
DEFAULT_TIMEOUT_S = 600.0

#: Where the operator keeps every release sent over the radio (beside the keys), so the
#: next update finds the version the swarm runs without `--base`.
RELEASES_DIR = "releases"


def _timeout(timeout: float | None) -> float:
    if timeout is None:
        return DEFAULT_TIMEOUT_S
    if not 0 < timeout < float("inf"):
        raise fail(f"--timeout must be a number of seconds > 0, got {timeout}")
    return timeout


def _open_ground_radio(url: str) -> Any:
    """The operator's radio: the same URLs as `fieldkit node --radio`, as the ground id."""
    from fieldkit.radio import open_radio
    from fieldkit.update.operator import GROUND_ID

    try:
        return open_radio(url, GROUND_ID)
    except (OSError, ValueError) as e:
        raise fail(f"--radio {url}: cannot open: {e}") from None


def _listen(session: Any, link: Any, url: str, hear: Any = None) -> dict[int, tuple[int, bytes]]:
    """What each robot runs, heard for LISTEN_S; exit 1 if no robot is heard."""
    from fieldkit.update.operator import run_session

    typer.echo(f"update: listening to the swarm on {url} for {LISTEN_S:g} s", err=True)
    run_session(session, link, seconds=LISTEN_S, say=typer.echo, until=lambda: False, hear=hear)
    running = session.running()
    if not running:
        raise fail(
            f"no robot heard on {url} in {LISTEN_S:g} s\n  hint: robots run `fieldkit node "
            "--state-dir DIR --keys DIR` with the same swarm key, on this radio's channel"
        )
    return running


def _known_release(
    prefix: bytes, base: Path | None, keys: Path, include: list[Path] | None
) -> Release | None:
    """The release whose hash starts with `prefix`: --base (a .bo, or the .bzz the robots
    were started with) or one this laptop sent before."""
    candidates: list[Path] = [base] if base is not None else []
    candidates += sorted((keys / RELEASES_DIR).glob("*.bo"))
    for path in candidates:
        try:
            if path.suffix == ".bzz":
                program = bvm.compile_file(path, include_dirs=[str(d) for d in include or []])
                release = Release.from_program(program)
            else:
                release = Release.read(path)
        except (FieldkitError, bvm.BuzzCompileError) as e:
            raise fail(e) from None
        if bytes.fromhex(release.hash).startswith(prefix):
            return release
    return None


def _start_state(positions: dict[int, tuple[float, float, float]]) -> Any:
    """The swarm as its bundles placed it, for the trial (None if nothing was heard)."""
    from fieldkit.robot import geo
    from fieldkit.sim.simulator import StartPose
    from fieldkit.sim.trial import StartState

    if not positions:
        return None
    lat0, lon0, _ = next(iter(positions.values()))
    frame = geo.LocalFrame(lat0, lon0, 0.0)
    poses = {}
    for rid, (lat, lon, alt) in positions.items():
        east, north, _ = frame.from_gps(lat, lon, 0.0)
        poses[rid] = StartPose(east, north, max(alt, 0.0), flying=alt > 1.0)
    return StartState(poses)


def _send_over_radio(
    script: Path,
    include: list[Path] | None,
    keys: Path,
    url: str,
    base: Path | None,
    version: int | None,
    profile: list[str] | None,
    timeout: float,
) -> None:
    """Listen, find the version the swarm runs, build and test the new one (from the swarm's
    own positions), send the patch and report robot by robot until all switched."""
    from fieldkit.robot import bundle as wirebundle
    from fieldkit.robot.bundle_auth import AuthError, Verifier, bundle_key, is_sealed
    from fieldkit.sim.trial import trial
    from fieldkit.update.keys import load_robot_keys, load_signing_key
    from fieldkit.update.operator import OperatorSession, run_session
    from fieldkit.update.pipeline import build, make_patch_file

    profiles = list(dict.fromkeys(profile or DEFAULT_PROFILES))
    _check_profiles(profiles)
    try:
        signing_key = load_signing_key(keys)
        swarm_key = load_robot_keys(keys).swarm_key
    except FieldkitError as e:
        raise fail(e) from None
    link = _open_ground_radio(url)
    positions: dict[int, tuple[float, float, float]] = {}

    # A signed swarm's bundles are checked as a robot checks them; a plain one's decoded.
    verifier = Verifier(bundle_key(swarm_key))

    def hear(data: bytes) -> None:
        try:
            b = wirebundle.decode(verifier.verify(data) if is_sealed(data) else data)
        except (wirebundle.BundleError, AuthError):
            return
        positions[b.robot] = (b.lat, b.lon, b.alt)

    try:
        session = OperatorSession(swarm_key)
        running = _listen(session, link, url, hear)
        hashes = {h for _, h in running.values()}
        if len(hashes) > 1:
            split = ", ".join(
                f"robot {r}: version {v} ({h.hex()})" for r, (v, h) in running.items()
            )
            raise fail(f"the swarm is split ({split})\n  hint: wait for it to agree, or --rollback")
        (prefix,) = hashes
        swarm_version = max(v for v, _ in running.values())
        base_release = _known_release(prefix, base, keys, include)
        if base_release is None:
            raise fail(
                f"the swarm runs version {swarm_version} ({prefix.hex()}...), of which this "
                f"laptop has no copy\n  hint: give --base OLD.bo, or the .bzz the robots were "
                "started with"
            )
        floor = max([swarm_version, *session.agent.bad])
        new_version = floor + 1 if version is None else version
        if new_version <= floor:
            raise fail(f"--version {version}: the swarm is at version {floor}; give more")
        start = _start_state(positions)
        try:
            new = build(
                script,
                [str(d) for d in include or []],
                test=lambda p: trial(p, profiles, start=start),
            )
            patch = make_patch_file(new, base_release, new_version, signing_key, swarm_key)
        except FieldkitError as e:
            raise fail(e) from None
        kept = keys / RELEASES_DIR / f"{new.hash}.bo"
        new.write(kept)
        write_version(kept, new_version)
        wrote(kept)
        typer.echo(
            f"update: sending version {new_version} ({base_release.hash[:12]} -> "
            f"{new.hash[:12]}, patch of {len(patch)} B) to {len(running)} robots on {url}"
        )
        session.send(patch, new_version, base_release.hash)
        took = run_session(session, link, seconds=timeout, say=typer.echo)
    except KeyboardInterrupt:
        raise fail("interrupted: the robots that have the patch go on with the update") from None
    finally:
        link.close()
    _finish(session, took, timeout)


def _rollback_over_radio(keys: Path, url: str, timeout: float) -> None:
    """Listen, find the swarm's newest version, order it rolled back, report until done."""
    from fieldkit.update.keys import load_robot_keys
    from fieldkit.update.operator import OperatorSession, run_session

    try:
        swarm_key = load_robot_keys(keys).swarm_key
    except FieldkitError as e:
        raise fail(e) from None
    link = _open_ground_radio(url)
    try:
        session = OperatorSession(swarm_key)
        running = _listen(session, link, url)
        newest = max(v for v, _ in running.values())
        if newest == 0:
            raise fail(
                "the swarm runs version 0, the version it started with: nothing to roll back to"
            )
        typer.echo(f"update: ordering version {newest} rolled back on {url}")
        session.order_rollback(newest)
        took = run_session(session, link, seconds=timeout, say=typer.echo)
    except KeyboardInterrupt:
        raise fail("interrupted: robots that heard the order go on rolling back") from None
    finally:
        link.close()
    _finish(session, took, timeout)


def _finish(session: Any, took: float, timeout: float) -> None:
    """Exit 0 with the outcome, or 1 saying why (rolled back, or time up and who is behind)."""
    outcome = session.outcome()
    if outcome is None:
        behind = ", ".join(str(r) for r in session.behind()) or "none heard"
        raise fail(f"no outcome after {timeout:g} s (--timeout): robots not there yet: {behind}")
    ok, why = outcome
    if not ok:
        raise fail(why)
    typer.echo(f"update: {why} ({took:.1f} s)")


def _check_profiles(profiles: list[str]) -> None:
    """Every --profile loads (before a compile and trial that would fail on it)."""
    from fieldkit.robot.profiles import load_profile

    for name in profiles:
        try:
            load_profile(name)
        except (OSError, ValueError) as e:
            raise fail(f"--profile {name!r}: {e}") from None


def _watch(originator: _Originator) -> None:
    """Run now, then on every save, until Ctrl-C or SIGTERM; a failed run says why and
    waits for the next save."""
    from fieldkit.update.monitor import Monitor

    def run() -> None:
        try:
            originator.run()
        except (FieldkitError, OSError) as e:
            report(e)
            typer.echo("update: not sent; waiting for the next save", err=True)

    monitor = Monitor(originator.script, originator.include_dirs, on_save=run)
    # Ctrl-C and SIGTERM (systemd's stop) end the watch after the run under way. Only the
    # main thread may take signals (a test may run the command in another).
    old: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, lambda *_: monitor.stop())
    typer.echo(f"update: watching {originator.script} and its includes; Ctrl-C stops", err=True)
    try:
        monitor.run(first=True)
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
    typer.echo(f"update: stopped watching after {monitor.runs} runs", err=True)


__all__ = ["DEFAULT_PROFILES", "update_cmd"]
