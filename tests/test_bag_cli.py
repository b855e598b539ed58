"""`fieldkit bag info` and `fieldkit bag from-tlog`: what they print, where they write, and
one `error:` line (exit 1) for every bag they cannot read."""

from __future__ import annotations

import hashlib
import random
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from bagdata import Sample, record
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.record.bag import MIN_MAX_BYTES, BagReader, BagWriter

runner = CliRunner()
FLIGHT = Path(__file__).resolve().parent / "data" / "tlogs" / "quad-flight-arducopter.tlog"


def make(path: Path, ticks: int, **kw: object) -> Sample:
    sample = Sample("cli")
    with BagWriter(path, fsync=False, **kw) as w:  # type: ignore[arg-type]
        record(w, sample, ticks)
    return sample


def info(path: Path) -> str:
    result = runner.invoke(app, ["bag", "info", str(path)])
    assert result.exit_code == 0, result.output
    assert result.stderr == ""
    return result.stdout


def fields(text: str) -> dict[str, str]:
    """`label: value` lines (the topic lines excepted)."""
    out = {}
    for line in text.splitlines():
        m = re.match(r"([a-z ]+):\s+(.*)", line)
        if m and m.group(1) != "topics":
            out[m.group(1)] = m.group(2)
    return out


def test_info_of_a_recording(tmp_path: Path) -> None:
    sample = make(tmp_path / "flight", 30)
    text = info(tmp_path / "flight")
    f = fields(text)
    assert f["path"] == str(tmp_path / "flight")
    assert f["storage"] == "ROS 2 bag, MCAP (1 part)"
    assert f["duration"] == "0:02.900 (2.9 s)"
    assert f["start"] == "2026-01-01 00:00:00.000 UTC"
    assert f["end"] == "2026-01-01 00:00:02.900 UTC"
    assert f["robot"] == "3" and f["seed"] == "12345"
    sha = hashlib.sha256(sample.meta.bo).hexdigest()
    assert f["script"] == f"hello.bzz (sha256 {sha})"
    assert f["keys"] == "swarm key 0123456789abcdef"
    assert f["recorded by"].startswith("fieldkit ")
    topics = {
        m.group(1): (int(m.group(2)), m.group(3))
        for m in re.finditer(r"(/\S+)\s+(\d+) msgs?\s+(\S+)", text)
    }
    assert topics["/fieldkit/tick"] == (30, "fieldkit_msgs/msg/Tick")
    assert topics["/fieldkit/meta"] == (1, "fieldkit_msgs/msg/Meta")
    assert topics["/mavlink/from"][1] == "mavros_msgs/msg/Mavlink"
    assert topics["/fix"] == (30, "sensor_msgs/msg/NavSatFix")
    assert topics["/gps/rx"] == (0, "fieldkit_msgs/msg/SerialChunk")  # a Husky's only
    assert topics["/autopilot/stream"] == (0, "fieldkit_msgs/msg/StreamSend")  # an M100's only
    assert len(topics) == 13 and topics["/update/outbox"] == (0, "fieldkit_msgs/msg/OutboxPatch")
    assert int(f["messages"]) == sum(n for n, _ in topics.values())
    assert "repaired" not in f


def test_info_of_parts_and_of_a_cut_recording(tmp_path: Path) -> None:
    now = [0.0]
    sample = Sample("cli")
    w = BagWriter(tmp_path / "r.bag", max_bytes=MIN_MAX_BYTES, fsync=False, clock=lambda: now[0])
    w.meta(sample.meta)
    for k in range(250):
        sample.write_tick(w, k)
        now[0] = (k + 1) * 0.1
    # Not closed: the last part is as a kill -9 leaves it.
    f = fields(info(tmp_path / "r.bag"))
    names = ", ".join(p.name for p in w.parts)
    assert f["storage"] == f"ROS 1 bag ({len(w.parts)} parts: {names})"
    assert f["repaired"].startswith(f"{w.parts[-1]}: not closed (no index)")
    assert "read by scanning" in f["repaired"]
    w.close()
    assert "repaired" not in fields(info(tmp_path / "r.bag"))


def _bad_bags(tmp_path: Path) -> dict[str, Path]:
    """A bag of each kind `bag info` must refuse."""
    good = tmp_path / "good"
    make(good, 5)
    bags = {}
    bags["missing"] = tmp_path / "nope"
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "empty.mcap").write_bytes(b"")
    bags["empty"] = tmp_path / "empty"
    (tmp_path / "garbage.bag").write_bytes(random.Random(1).randbytes(9000))
    bags["garbage"] = tmp_path / "garbage.bag"
    shutil.copytree(good, tmp_path / "corrupt")
    mcap = tmp_path / "corrupt" / "good.mcap"
    data = bytearray(mcap.read_bytes())
    data[300:340] = bytes(40)  # inside the first chunk: the meta's
    mcap.write_bytes(bytes(data))
    bags["corrupt"] = tmp_path / "corrupt"
    return bags


def test_info_refuses_what_it_cannot_read_with_one_error_line(tmp_path: Path) -> None:
    for kind, path in _bad_bags(tmp_path).items():
        result = runner.invoke(app, ["bag", "info", str(path)])
        assert result.exit_code == 1, (kind, result.output)
        lines = result.stderr.splitlines()
        assert lines[0].startswith(f"error: {path}"), (kind, result.stderr)
        assert len(lines) == 2 and lines[1].startswith("hint: "), (kind, result.stderr)
        assert result.stdout == "" and "Traceback" not in result.output


def test_the_console_script_too(tmp_path: Path) -> None:
    path = _bad_bags(tmp_path)["garbage"]
    proc = subprocess.run(
        [sys.executable, "-m", "fieldkit", "bag", "info", str(path)],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert proc.returncode == 1 and proc.stderr.startswith(f"error: {path}: unreadable")
    assert "Traceback" not in proc.stderr


def test_from_tlog_says_where_it_wrote_and_what(tmp_path: Path) -> None:
    prefix = tmp_path / "short.tlog"
    # Whole records, then 9 bytes: a time and a start byte, too short for a record.
    prefix.write_bytes(FLIGHT.read_bytes()[:200_000])
    result = runner.invoke(app, ["bag", "from-tlog", str(prefix), "-o", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    assert result.stderr == f"wrote {tmp_path / 'b'}\n"
    m = re.fullmatch(
        r"(\d+) records over ([\d.]+) s: (\d+) MAVLink messages \((\d+) records held none "
        r"that decode\); skipped 9 bytes of garbage in 1 place; (\d+) positions, "
        r"(\d+) battery readings; robot 1\n",
        result.stdout,
    )
    assert m, result.stdout
    r = BagReader(tmp_path / "b")
    assert int(m.group(1)) == r.count("/autopilot/rx")
    assert int(m.group(3)) == r.count("/mavlink/from")
    assert int(m.group(5)) == r.count("/fix") and int(m.group(6)) == r.count("/battery")
    f = fields(info(tmp_path / "b"))
    assert f["source"] == "tlog short.tlog (no node outputs to verify)"
    assert f["script"] == "none recorded" and f["robot"] == "1"
    again = runner.invoke(app, ["bag", "from-tlog", str(prefix), "-o", str(tmp_path / "b")])
    assert again.exit_code == 1 and "exists already" in again.stderr


@pytest.mark.parametrize(
    ("args", "status", "text"),
    [
        (["bag", "from-tlog", "{d}/none.tlog", "-o", "{d}/x"], 1, "cannot read"),
        (["bag", "from-tlog", "{d}/empty.tlog", "-o", "{d}/x"], 1, "empty file"),
        (["bag", "from-tlog", "{d}/empty.tlog"], 2, "Missing option"),
        (["bag", "info"], 2, "Missing argument"),
        (["bag", "plot-nothing"], 2, "No such command"),
    ],
)
def test_exit_codes(tmp_path: Path, args: list[str], status: int, text: str) -> None:
    (tmp_path / "empty.tlog").write_bytes(b"")
    result = runner.invoke(app, [a.format(d=tmp_path) for a in args])
    assert result.exit_code == status, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and text in errors[0], result.stderr


def test_info_survives_nonsense_times_in_metadata(tmp_path: Path) -> None:
    """A metadata.yaml edited or damaged so that its times are no dates (a fuzz find)."""
    make(tmp_path / "b", 3)
    meta = tmp_path / "b" / "metadata.yaml"
    text = meta.read_text()
    meta.write_text(
        re.sub(
            r"nanoseconds_since_epoch: \d+", "nanoseconds_since_epoch: 9999999999999999999999", text
        )
    )
    f = fields(info(tmp_path / "b"))
    assert f["start"] == "9999999999999999999999 ns since the epoch (not a date)"


@pytest.mark.long
def test_bag_plot_draws_a_node_bag_and_a_tlog_bag(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app

    runner = CliRunner()
    node_bag = Path(__file__).parent / "data" / "bags" / "sitl-climb" / "robot1"
    png = tmp_path / "climb.png"
    result = runner.invoke(app, ["bag", "plot", str(node_bag), "-o", str(png)])
    assert result.exit_code == 0, result.output
    assert f"wrote {png}" in result.stderr and png.read_bytes()[:4] == b"\x89PNG"
    tlog = Path(__file__).parent / "data" / "tlogs" / "quad-flight-arducopter.tlog"
    bag = tmp_path / "flight"
    assert runner.invoke(app, ["bag", "from-tlog", str(tlog), "-o", str(bag)]).exit_code == 0
    result = runner.invoke(app, ["bag", "plot", str(bag), "-o", str(tmp_path / "tlog.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "tlog.png").stat().st_size > 20_000
    result = runner.invoke(app, ["bag", "plot", str(tmp_path / "nope"), "-o", str(png)])
    assert result.exit_code == 1 and result.stderr.startswith("error: ")
