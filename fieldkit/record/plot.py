"""`fieldkit bag plot`: what an operator looks at first after a flight, in one picture.

Four panels from a recorded `Flight`: the track (east and north of the home, from the GPS
the script saw, coloured by the script's state), the altitude, the battery (voltage and
percent), and the script's state over time with the safety supervisor's events marked.
"""

from __future__ import annotations

import math
from pathlib import Path

from fieldkit.plotting import figure, save
from fieldkit.record.flight import Flight
from fieldkit.robot import geo


def _num(v: object) -> float:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan


def plot_flight(flight: Flight, path: Path, title: str | None = None) -> Path:
    """Draw `flight` into the PNG `path`; returns it."""
    ticks = flight.ticks
    t0 = ticks[0].clock_s if ticks else 0.0
    times = [t.clock_s - t0 for t in ticks]
    lats = [_num(t.sensors.get("lat")) for t in ticks]
    lons = [_num(t.sensors.get("lon")) for t in ticks]
    home = flight.meta.get("home")
    if isinstance(home, list) and len(home) >= 2:
        origin = (float(home[0]), float(home[1]))
    else:
        first = next(((a, o) for a, o in zip(lats, lons, strict=True) if math.isfinite(a)), None)
        origin = first or (0.0, 0.0)
    frame = geo.LocalFrame(origin[0], origin[1], 0.0)
    east, north = [], []
    for lat, lon in zip(lats, lons, strict=True):
        if math.isfinite(lat) and math.isfinite(lon):
            e, n, _ = frame.from_gps(lat, lon)
        else:
            e = n = math.nan
        east.append(e)
        north.append(n)
    states = [t.state or "" for t in ticks]
    names = sorted(set(states))
    index = {name: k for k, name in enumerate(names)}

    fig, axes = figure(2, 2, (12.0, 8.0))
    track, alt, battery, state = axes[0][0], axes[0][1], axes[1][0], axes[1][1]
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if len(names) <= 10 else "tab20"]
    for name in names:
        pts = [(e, n) for e, n, s in zip(east, north, states, strict=True) if s == name]
        track.scatter(
            [p[0] for p in pts], [p[1] for p in pts], s=6, color=cmap(index[name]),
            label=name or "(none)",
        )  # fmt: skip
    track.plot([0], [0], marker="x", color="black", label="home")
    track.set_xlabel("east (m)")
    track.set_ylabel("north (m)")
    track.set_aspect("equal", adjustable="datalim")
    track.set_title("track, by script state")
    track.legend(fontsize=7, loc="best")

    alt.plot(times, [_num(t.sensors.get("alt")) for t in ticks], color="tab:blue")
    alt.set_ylabel("altitude above home (m)")
    alt.set_xlabel("time (s)")
    alt.set_title("altitude")

    battery.plot(times, [_num(t.sensors.get("voltage")) for t in ticks], color="tab:red")
    battery.set_ylabel("voltage (V)", color="tab:red")
    percent = battery.twinx()
    percent.plot(times, [_num(t.sensors.get("battery_percent")) for t in ticks], color="tab:green")
    percent.set_ylabel("battery (%)", color="tab:green")
    battery.set_xlabel("time (s)")
    battery.set_title("battery")

    state.step(times, [index[s] for s in states], where="post", color="tab:purple")
    state.set_yticks(range(len(names)), [n or "(none)" for n in names])
    marked = False
    for t, tick in zip(times, ticks, strict=True):
        for event in tick.events:
            state.axvline(t, color="tab:orange", lw=0.8, label=None if marked else "supervisor")
            state.annotate(event[:40], (t, 0), fontsize=6, rotation=90, va="bottom")
            marked = True
    state.set_xlabel("time (s)")
    state.set_title("script state and supervisor events")
    if marked:
        state.legend(fontsize=7, loc="upper left")
    robot = flight.meta.get("robot_id", "?")
    script = flight.meta.get("script_name", "")
    fig.suptitle(title or f"robot {robot}: {script}, {len(ticks)} ticks")
    save(fig, path)
    return path


def plot_bag(bag: Path, path: Path) -> Path:
    """Draw the recording `bag` into the PNG `path` (BagError if it is not one). A node's or
    a simulated robot's bag is drawn from its ticks; an autopilot log's from its /fix and
    /battery (it has no script, so no state)."""
    from fieldkit.record.bag import BagReader
    from fieldkit.record.flight import FlightTick
    from fieldkit.record.flight_bag import read_flight

    reader = BagReader(bag)
    if reader.count("/fieldkit/tick"):
        return plot_flight(read_flight(bag), path)
    flight = Flight({"robot_id": reader.meta.robot_id, "script_name": "autopilot log"}, "", b"")
    batteries = list(reader.batteries())
    k = 0
    for n, fix in enumerate(reader.fixes()):
        while k + 1 < len(batteries) and batteries[k + 1].unix_ns <= fix.unix_ns:
            k += 1
        battery = batteries[k] if batteries else None
        sensors: dict[str, object] = {
            "lat": fix.lat if fix.has_fix else math.nan,
            "lon": fix.lon if fix.has_fix else math.nan,
            "alt": fix.alt,
            "voltage": math.nan if battery is None else battery.voltage,
            "battery_percent": math.nan if battery is None else battery.percent,
        }
        flight.ticks.append(FlightTick(n, fix.unix_ns / 1e9, fix.unix_ns, sensors=sensors))
    if not flight.ticks:
        from fieldkit.record.bag import BagError

        raise BagError(bag, "holds no positions to draw", "`fieldkit bag info` says what it holds")
    return plot_flight(flight, path)


__all__ = ["plot_bag", "plot_flight"]
