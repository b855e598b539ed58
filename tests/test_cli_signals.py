"""Ctrl-C and SIGTERM end a long run normally: results written, exit 0."""

from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from fieldkit.cli.signals import stop_on_signals

ROOT = Path(__file__).resolve().parents[1]


def test_the_first_ctrl_c_sets_the_event_the_second_interrupts() -> None:
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with stop_on_signals() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(10)
    with stop_on_signals() as stop:
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt: wherever it lands
        assert stop.wait(10)
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            threading.Event().wait(10)  # the handler runs here, at the latest
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_a_ctrl_c_during_a_garbage_collection_is_not_lost() -> None:
    # Python's own handler would raise KeyboardInterrupt inside the collector's callback,
    # which prints it and drops it: the run would go on.
    def collecting(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(1000))  # bytecode to run the handler in, inside the callback

    with stop_on_signals() as stop:
        gc.callbacks.append(collecting)
        try:
            gc.collect()
        finally:
            gc.callbacks.remove(collecting)
        assert stop.is_set()


def test_outside_the_main_thread_nothing_is_installed() -> None:
    seen: list[object] = []

    def run() -> None:
        with stop_on_signals() as stop:
            seen.append(signal.getsignal(signal.SIGINT))
            seen.append(stop.is_set())

    before = signal.getsignal(signal.SIGINT)
    t = threading.Thread(target=run)
    t.start()
    t.join()
    assert seen == [before, False]


def test_ctrl_c_ends_a_sim_run_with_its_ground_station_and_writes_the_results(
    tmp_path: Path,
) -> None:
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "sim", "run",
         str(ROOT / "buzz_scripts" / "examples" / "hello.bzz"), "--robots", "3",
         "--ground", "--ground-port", "0", "--out", str(out), "--seconds", "600"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stderr is not None
    lines = []
    for line in proc.stderr:  # the run has started once it says so
        lines.append(line)
        if "in real time for 600 s" in line:
            break
    assert proc.poll() is None, "".join(lines)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, "".join(lines) + stderr
    assert "ground: stopped" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robots"] == 3
    assert summary["seconds_simulated"] < 600  # ended by Ctrl-C, not by its time
    assert f"results in {out}" in stdout


@pytest.mark.parametrize("workers", [None, 2])
def test_ctrl_c_ends_a_sim_run_early_writes_what_it_ran_and_fails(
    tmp_path: Path, workers: int | None
) -> None:
    out = tmp_path / "run"
    split = [] if workers is None else ["--workers", str(workers)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "sim", "run",
         str(ROOT / "buzz_scripts" / "examples" / "hello.bzz"), "--robots", "4",
         "--out", str(out), "--seconds", "100000", *split],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,  # its own process group, as a terminal's job is
    )  # fmt: skip
    assert proc.stderr is not None
    lines = []
    for line in proc.stderr:  # the 0% line: the handlers are in, stepping begins
        lines.append(line)
        if "robots" in line and "0% (0/" in line:
            break
    assert proc.poll() is None, "".join(lines)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C does: every process of the job
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 1, "".join(lines) + stderr
    assert "Traceback" not in stderr, stderr
    summary = json.loads((out / "summary.json").read_text())
    done = summary["seconds_simulated"]
    assert 0 <= done < 100000  # ended by Ctrl-C, not by its time
    assert f"error: interrupted at {done:g} s of 100000 s" in stderr
    assert (out / "log.txt").exists() and (out / "trajectories.csv").exists()
    assert f"results in {out}" in stdout
