"""fieldkit's figures: an experiment's plot.png (the paper's figure) and bytes.png (the radio
load), and the tracks of a `sim run` or `sitl` run (`plot_tracks`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fieldkit.plotting import figure, save
from fieldkit.robot.bundle_auth import SEALED_MAX_MSG_SIZE
from fieldkit.sim.experiments.base import (
    BUNDLE_LIMIT_BYTES,
    MISSION_S,
    XBEE_FRAME_BYTES,
    RunResult,
    RunSpec,
)

if TYPE_CHECKING:
    from fieldkit.sim.experiments.plan import Plan
    from fieldkit.sim.tracks import Tracks


def _label(plan: Plan, spec: RunSpec) -> str:
    """A cell's legend: what varies across the grid (drop rate, robot count)."""
    parts = []
    if len(plan.robots) > 1 or len(plan.drops) == 1:
        shape = f" ({spec.shape})" if spec.shape else ""
        parts.append(f"{spec.robots} robots{shape}")
    if len(plan.drops) > 1 or spec.drop:
        parts.append(f"drop {spec.drop:g}")
    if spec.burst is not None and spec.drop:
        parts.append(f"bursts of {spec.burst:g}")
    return ", ".join(parts)


def _cells(plan: Plan, results: Sequence[RunResult]) -> list[tuple[RunSpec, list[RunResult]]]:
    """The results grouped by (robots, drop), in grid order."""
    out = []
    for n in plan.robots:
        for d in plan.drops:
            rs = [r for r in results if r.spec.robots == n and r.spec.drop == d]
            if rs:
                out.append((rs[0].spec, rs))
    return out


def _band(
    rs: Sequence[RunResult], column: str
) -> tuple[list[float], list[float], list[float], list[float]]:
    """(times, mean, low, high) of one column over the runs of a cell, sample by sample."""
    times = [float(row["t_s"]) for row in rs[0].rows]
    mean, low, high = [], [], []
    for k in range(len(times)):
        values = [float(r.rows[k][column]) for r in rs if k < len(r.rows)]
        values = [v if math.isfinite(v) else math.nan for v in values]
        finite = [v for v in values if not math.isnan(v)]
        mean.append(sum(finite) / len(finite) if finite else math.nan)
        low.append(min(finite) if finite else math.nan)
        high.append(max(finite) if finite else math.nan)
    return times, mean, low, high


def plot_experiment(plan: Plan, results: Sequence[RunResult], path: Path) -> None:
    """The paper's figure: the experiment's metric over time, per cell (mean, min-max band)."""
    e = plan.experiment
    per_robot = e.plots_each_robot()
    fig, axes = figure(1, 2 if per_robot else 1, (12.0, 4.5) if per_robot else (8.0, 4.5))
    ax = axes[0][0]
    for spec, rs in _cells(plan, results):
        times, mean, low, high = _band(rs, e.series)
        line = ax.plot(times, mean, label=_label(plan, spec))[0]
        if len(rs) > 1:
            ax.fill_between(times, low, high, color=line.get_color(), alpha=0.15, lw=0)
    ax.axvline(MISSION_S, color="grey", ls=":", lw=1)
    events = e.events()
    for t, _ in events:
        ax.axvline(t, color="red", ls="--", lw=1)
    marks = "".join(f"; dashed: {what}" for _, what in events[:1])
    ax.set_xlabel(f"simulated time (s); dotted: mission command{marks}")
    runs = f", mean and range of {plan.runs} runs" if plan.runs > 1 else ""
    drop = f", drop {plan.drops[0]:g}" if len(plan.drops) == 1 else ""
    ax.set_title(f"{e.name} ({e.figure}){drop}{runs}", fontsize=10)
    if per_robot:
        ax.set_ylabel("mean " + e.metric)
        ax.set_yscale("log")
        ax.axhline(1.0, color="red", ls="--", lw=1, label="1 m target")
    else:
        ax.set_ylabel(e.metric)
        if e.y_limits is not None:
            ax.set_ylim(*e.y_limits)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if per_robot:
        # Figure 12 shows every robot: here those of the first run at the highest drop rate.
        spec, rs = _cells(plan, results)[-1]
        ax2 = axes[0][1]
        run = rs[0]
        for rid in range(1, spec.robots + 1):
            pts = [row for row in run.robot_rows if row["robot"] == rid]
            ax2.plot(
                [float(p["t_s"]) for p in pts],
                [max(float(p["centroid_distance_m"]), 1e-3) for p in pts],
                lw=1,
                label=f"robot {rid}" if spec.robots <= 10 else None,
            )
        ax2.axhline(1.0, color="red", ls="--", lw=1)
        ax2.axvline(MISSION_S, color="grey", ls=":", lw=1)
        ax2.set_yscale("log")
        ax2.set_xlabel("simulated time (s)")
        ax2.set_ylabel("distance to the ideal centroid (m)")
        ax2.set_title(f"each robot, {_label(plan, spec)}, seed {run.spec.seed}", fontsize=10)
        ax2.grid(alpha=0.3)
        if spec.robots <= 10:
            ax2.legend(fontsize=7, ncol=2)
    save(fig, path)


def plot_bytes(plan: Plan, results: Sequence[RunResult], path: Path) -> None:
    """Figure 10: bytes per robot per step on the air (vs the XBee frame) and bundle content."""
    fig, axes = figure(2, 1, (8.0, 7.0))
    top, bottom = axes[0][0], axes[1][0]
    for spec, rs in _cells(plan, results):
        times, mean, _, _ = _band(rs, "air_bytes_mean")
        _, peak, _, _ = _band(rs, "air_bytes_max")
        line = top.plot(times, mean, label=_label(plan, spec))[0]
        top.plot(times, peak, color=line.get_color(), ls=":", lw=0.8)
        times, content, _, _ = _band(rs, "bundle_bytes_mean")
        bottom.plot(times, content, color=line.get_color(), label=_label(plan, spec))
    top.axhline(XBEE_FRAME_BYTES, color="red", ls="--", lw=1, label="XBee frame (250 B)")
    top.axhline(XBEE_FRAME_BYTES / 2, color="orange", ls="--", lw=1, label="half a frame")
    top.set_ylabel("bytes on the air per robot per step")
    top.set_title(f"{plan.experiment.name}: radio load (solid: mean, dotted: max)", fontsize=10)
    if plan.swarm_key is None:
        bottom.axhline(
            BUNDLE_LIMIT_BYTES, color="red", ls="--", lw=1, label="ROSBuzz limit (190 B)"
        )
    else:
        limit = SEALED_MAX_MSG_SIZE
        bottom.axhline(limit, color="red", ls="--", lw=1, label=f"signed bundle limit ({limit} B)")
    bottom.axhline(XBEE_FRAME_BYTES / 2, color="orange", ls="--", lw=1, label="half a frame")
    bottom.set_ylabel("Buzz bundle content per robot per step (mean)")
    bottom.set_xlabel("simulated time (s)")
    for ax in (top, bottom):
        ax.set_ylim(0, XBEE_FRAME_BYTES + 20)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    save(fig, path)


#: Tracks of swarms larger than this are drawn as points only (lines would be a smear).
_TRACK_LINES_MAX = 200


def plot_tracks(tracks: Tracks, path: Path, title: str) -> None:
    """A run's plot.png: every robot's track, coloured by its state (or flight mode) at each
    sample, with a ring where it started; below, the radio load over time."""
    fig, axes = figure(2, 1, (8.0, 10.0))
    ax, load = axes[0][0], axes[1][0]
    samples = tracks.samples
    if len(tracks.ids) <= _TRACK_LINES_MAX:
        for k in range(len(tracks.ids)):
            ax.plot(
                [s.east[k] for s in samples],
                [s.north[k] for s in samples],
                color="grey",
                lw=0.6,
                alpha=0.5,
                zorder=1,
            )
    if samples:
        ax.scatter(
            samples[0].east,
            samples[0].north,
            s=30,
            facecolors="none",
            edgecolors="black",
            lw=0.6,
            zorder=3,
            label="start",
        )
    names = sorted({str(state) for s in samples for state in s.states})
    colours = _state_colours(names)
    size = 12 if len(tracks.ids) <= _TRACK_LINES_MAX else 3
    for name in names:
        east = [
            e for s in samples for e, st in zip(s.east, s.states, strict=True) if str(st) == name
        ]
        north = [
            n for s in samples for n, st in zip(s.north, s.states, strict=True) if str(st) == name
        ]
        label = name if name != "None" else f"no {tracks.state_column}"
        ax.scatter(east, north, s=size, color=colours[name], zorder=2, label=label)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east of home (m)")
    ax.set_ylabel("north of home (m)")
    what = "state" if tracks.state_column == "state" else "flight mode"
    ax.set_title(f"{title}: tracks by {what}, one point a second", fontsize=10)
    ax.grid(alpha=0.3)
    if names:
        ax.legend(fontsize=7, loc="best", ncol=2 if len(names) > 8 else 1)
    times = [s.t_s for s in tracks.load]
    load.plot(times, [s.mean for s in tracks.load], label="mean over robots")
    load.plot(times, [s.max for s in tracks.load], ls=":", label="max")
    if tracks.load_unit == "step":
        load.axhline(XBEE_FRAME_BYTES, color="red", ls="--", lw=1, label="XBee frame (250 B)")
    load.set_xlabel("time (s)")
    load.set_ylabel(f"bytes on the air per robot per {tracks.load_unit}")
    load.set_title("radio load", fontsize=10)
    load.set_ylim(bottom=0)
    load.grid(alpha=0.3)
    load.legend(fontsize=7, loc="upper right")
    save(fig, path)


def _state_colours(names: list[str]) -> dict[str, Any]:
    """A distinct colour per state name (tab10, then tab20 for more), grey for none."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if len(names) <= 10 else "tab20"]
    return {
        name: "lightgrey" if name == "None" else cmap(k % cmap.N) for k, name in enumerate(names)
    }
