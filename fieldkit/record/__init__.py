"""Flight recordings: every byte a robot exchanged and every tick it ran, as a rosbag.

`bag` writes and reads them (`BagWriter`, `BagReader`; the layout is in docs/recording.md),
`types` holds their message types, `scan` reads a bag cut short by a crash, `tlog` turns a
MAVLink telemetry log into one, `info` describes one (`fieldkit bag info`). This package may
import `robot`, `vehicle` and `radio`, never `node`, `sim` or `cli`.
"""

from __future__ import annotations

from fieldkit.record.bag import (
    BagError,
    BagReader,
    BagWriter,
    Battery,
    Fix,
    MavlinkFrame,
    Meta,
    RadioFrame,
    SerialChunk,
    TickRow,
    TopicInfo,
)

__all__ = [
    "BagError",
    "BagReader",
    "BagWriter",
    "Battery",
    "Fix",
    "MavlinkFrame",
    "Meta",
    "RadioFrame",
    "SerialChunk",
    "TickRow",
    "TopicInfo",
]
