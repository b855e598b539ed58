"""A node's `--record PATH`: its flight, streamed into a rosbag as it flies.

The recorder taps the autopilot link from the moment it opens (the start-up's bytes are
part of the recording), and the bag is opened once the node is built, when everything its
meta holds is known (`replay.recording_meta`): the meta first, then the start-up, then each
tick as it ends. The bag writer flushes every second, so a power cut loses at most that.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import bvm
from fieldkit.node.node import Node
from fieldkit.node.replay import recording_meta, tap_link
from fieldkit.record.bag import BagWriter
from fieldkit.record.flight import Flight, FlightRecorder, FlightTick
from fieldkit.record.flight_bag import FlightBag
from fieldkit.robot.profiles import Profile
from fieldkit.robot.rc import RcCommand
from fieldkit.update.release import Release
from fieldkit.vehicle.links import VehicleLink

#: The most a node's recording may take on disk, all its parts together, by default.
DEFAULT_MAX_TOTAL_BYTES = 2 * 1024**3
#: Ticks between two looks at the recording's size on disk.
SIZE_CHECK_TICKS = 10


def _size(path: Path) -> int:
    """Bytes of a part: a ROS 1 file, or a ROS 2 directory's files."""
    try:
        if path.is_dir():
            return sum(f.stat().st_size for f in path.iterdir() if f.is_file())
        return path.stat().st_size
    except OSError:
        return 0


def new_flight_path(folder: Path, now: float | None = None) -> Path:
    """A new bag's path under the config's `record.dir`: `flight-<UTC time>` (a ROS 2
    directory), made unique with `-2`, `-3`... when the clock repeats (a restart within a
    second, a clock not yet set at boot)."""
    import time

    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(time.time() if now is None else now))
    path = folder / f"flight-{stamp}"
    n = 2
    while path.exists() or Path(f"{path}_1").exists():
        path = folder / f"flight-{stamp}-{n}"
        n += 1
    return path


def prune_flights(folder: Path, keep_mb: float, *, room_mb: float) -> list[Path]:
    """Remove the oldest flights under `folder` until they and a new one of `room_mb` fit
    in `keep_mb` (the config's `record.keep_mb`); the removed ones, oldest first.

    Only `flight-*` entries are touched (the names `new_flight_path` gives), oldest by
    modification time, and never the last one left: the most recent flight is what an
    operator asks for after a crash."""
    import shutil

    try:
        flights = sorted(
            (p for p in folder.glob("flight-*") if not p.is_symlink()),
            key=lambda p: (p.stat().st_mtime, p.name),
        )
    except OSError:
        return []
    budget = keep_mb * 2**20 - room_mb * 2**20
    total = sum(_size(p) for p in flights)
    removed: list[Path] = []
    while total > budget and len(flights) > 1:
        oldest = flights.pop(0)
        total -= _size(oldest)
        if oldest.is_dir():
            shutil.rmtree(oldest, ignore_errors=True)
        else:
            oldest.unlink(missing_ok=True)
        removed.append(oldest)
    return removed


class NodeRecording:
    """One flight's recording: `tap` the link, `begin` once the node exists, `close` at the end.

    The bag rotates into parts (`BagWriter`'s `max_bytes`); all parts together stay under
    `max_total_bytes`: past it the recording stops, keeping the flight's beginning (what a
    replay starts from), and says so once, so a day in the field never fills the disk."""

    def __init__(
        self,
        path: Path,
        profile: Profile,
        program: bvm.Program,
        *,
        max_total_bytes: int = DEFAULT_MAX_TOTAL_BYTES,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.path = path
        self.max_total_bytes = max_total_bytes
        self.say = say
        self.stopped = False
        self._ticks = 0
        release = Release.from_program(program)
        text = profile.path.read_text(encoding="utf-8") if profile.path is not None else ""
        self.flight = Flight({}, text, release.bo, release.bdb, release.bpos)
        self.recorder = FlightRecorder(self.flight, keep=False)
        self.writer: BagWriter | None = None

    def tap(self, link: VehicleLink) -> None:
        """Record the link's bytes from now on (the start-up's included): the autopilot's
        both ways, a separate GPS receiver's (a Clearpath base), and when the link's own
        thread sends (the DJI movement stream)."""
        tap_link(link, self.recorder)

    def begin(
        self,
        node: Node,
        link: VehicleLink,
        *,
        script_name: str,
        seed: int,
        globals_: dict[str, object],
        commands: Sequence[RcCommand],
    ) -> None:
        """Open the bag and write what precedes the first tick; BagError if it cannot."""
        self.flight.meta = recording_meta(
            node, link, script_name=script_name, seed=seed, globals_=globals_, commands=commands
        )
        self.writer = BagWriter(self.path)
        bag = FlightBag(self.writer)
        bag.start(self.flight)
        self.flight.startup_rx, self.flight.startup_tx = [], []  # written: not kept

        def tick(t: FlightTick) -> None:
            if self.stopped:
                return
            bag.tick(t)
            self._ticks += 1
            if self._ticks % SIZE_CHECK_TICKS == 0:
                self._check_size()

        self.recorder.on_tick = tick

    def _check_size(self) -> None:
        """Stop recording once the parts together reach the cap."""
        writer = self.writer
        assert writer is not None
        total = sum(_size(p) for p in writer.parts)
        if total >= self.max_total_bytes:
            self.stopped = True
            writer.close()
            if self.say is not None:
                self.say(
                    f"recording stopped: {self.path} reached {total / 2**20:.0f} MiB, its cap "
                    f"(--record-max-mb); the flight goes on unrecorded"
                )

    def close(self) -> None:
        """Close the bag (what the ticks wrote is already flushed)."""
        if self.writer is not None and not self.stopped:
            self.writer.close()


__all__ = ["NodeRecording"]
