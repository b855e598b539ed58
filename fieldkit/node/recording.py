"""A node's `--record PATH`: its flight, streamed into a rosbag as it flies.

The recorder taps the autopilot link from the moment it opens (the start-up's bytes are
part of the recording), and the bag is opened once the node is built, when everything its
meta holds is known (`replay.recording_meta`): the meta first, then the start-up, then each
tick as it ends. The bag writer flushes every second, so a power cut loses at most that.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import bvm
from fieldkit.node.node import Node
from fieldkit.node.replay import recording_meta
from fieldkit.record.bag import BagWriter
from fieldkit.record.flight import Flight, FlightRecorder
from fieldkit.record.flight_bag import FlightBag
from fieldkit.robot.profiles import Profile
from fieldkit.robot.rc import RcCommand
from fieldkit.update.release import Release
from fieldkit.vehicle.link import Autopilot


class NodeRecording:
    """One flight's recording: `tap` the link, `begin` once the node exists, `close` at the end."""

    def __init__(self, path: Path, profile: Profile, program: bvm.Program) -> None:
        self.path = path
        release = Release.from_program(program)
        text = profile.path.read_text(encoding="utf-8") if profile.path is not None else ""
        self.flight = Flight({}, text, release.bo, release.bdb, release.bpos)
        self.recorder = FlightRecorder(self.flight, keep=False)
        self.writer: BagWriter | None = None

    def tap(self, link: Autopilot) -> None:
        """Record the link's bytes from now on (the start-up's included)."""
        link.on_rx, link.on_tx = self.recorder.autopilot_rx, self.recorder.autopilot_tx

    def begin(
        self,
        node: Node,
        link: Autopilot,
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
        self.recorder.on_tick = bag.tick

    def close(self) -> None:
        """Close the bag (what the ticks wrote is already flushed)."""
        if self.writer is not None:
            self.writer.close()


__all__ = ["NodeRecording"]
