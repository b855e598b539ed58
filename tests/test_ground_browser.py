"""A real browser drives the ground station's page against a running simulation: Debian's
Chromium, headless, through Playwright (pointed at the installed browser; Playwright's own
browser download is never used). Skipped, saying why, only where no browser can be had."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
#: The flags that keep Chromium off the network in this sandbox (docs/ground.md#tests).
FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip

playwright = pytest.importorskip(
    "playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')"
)
if not os.path.exists(CHROMIUM):
    pytest.skip(
        "no Chromium at /usr/bin/chromium (apt-get install chromium; .ci/run installs it as root)",
        allow_module_level=True,
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _states(page: object) -> list[str]:
    return page.eval_on_selector_all(  # type: ignore[attr-defined, no-any-return]
        "#robots tbody tr", "rows => rows.map(r => r.children[2].textContent)"
    )


@pytest.mark.long
def test_page_takes_off_and_allocates_tasks(tmp_path: Path) -> None:
    port = _free_port()
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "sim", "run", "task_allocation.bzz", "--robots", "5",
         "--out", str(out), "--ground", "--ground-port", str(port), "--seconds", "400"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")))  # type: ignore[union-attr]
    reader.start()
    try:
        deadline = time.monotonic() + 120
        while not any("page at" in line for line in lines):
            assert proc.poll() is None, "".join(lines)
            assert time.monotonic() < deadline, "".join(lines)
            time.sleep(0.2)
        with playwright.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
            page = browser.new_page(viewport={"width": 1500, "height": 1000})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function(
                "document.querySelectorAll('#robots tbody tr').length === 5", timeout=60_000
            )
            assert page.inner_text("#link") == "live"
            # A dangerous command asks first; cancelling sends nothing.
            page.click("#btn-land")
            assert page.is_visible("#modal")
            page.click("#modal-no")
            assert page.eval_on_selector_all("#commands tbody tr", "r => r.length") == 0
            page.click("#btn-takeoff")
            page.wait_for_function(
                "[...document.querySelectorAll('#robots tbody tr')]"
                ".every(r => r.children[2].textContent === 'IDLE')",
                timeout=120_000,
            )
            # A reload (a browser that disconnects and comes back) picks the stream up again.
            page.reload()
            page.wait_for_function(
                "document.querySelectorAll('#robots tbody tr').length === 5", timeout=60_000
            )
            page.click("#btn-ta")
            page.wait_for_function(
                "[...document.querySelectorAll('#robots tbody tr')]"
                ".every(r => ['JOINED', 'LOCK'].includes(r.children[2].textContent))",
                timeout=240_000,
            )
            assert set(_states(page)) <= {"JOINED", "LOCK"}
            acked = page.inner_text("#commands tbody tr:first-child td:nth-child(2)")
            assert acked == "1, 2, 3, 4, 5"
            shot = tmp_path / "ground.png"
            page.screenshot(path=str(shot))
            if os.environ.get("FIELDKIT_UPDATE_SCREENSHOT"):
                shutil.copy(shot, ROOT / "docs" / "ground.png")
            browser.close()
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl-C: a normal end of a --ground run
        try:
            proc.wait(60)
        finally:
            if proc.poll() is None:
                proc.kill()
            reader.join(10)
    assert proc.returncode == 0, "".join(lines)
    assert (out / "summary.json").exists()
