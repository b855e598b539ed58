"""Deploy killed at any point, and two deploys at once: real `fieldkit deploy` processes.

FIELDKIT_DEPLOY_CRASH_AFTER=N has a deploy SIGKILL itself right after its Nth change to the
file system (N:STOP stops it there instead), so each kill point is reached deterministically,
whatever the machine's speed. After a kill, deploy run again must leave exactly the tree a
deploy that was never killed leaves: no half-written file, no staged leftover, nothing lost
from the manifest.
"""

from __future__ import annotations

import os
import shutil
import signal
from pathlib import Path

import pytest

from fieldkit.deploy.install import CRASH_ENV, Manifest

from .kit import HELLO, TASKS, deploy, dji_app_key, errors, fieldkit, listing, m100

#: The two deploys of the upgrade case: the second changes the profile, the script (its
#: includes go), the robot id, the links and the udev rules (three: the Husky's MCU, XBee
#: and GPS receiver), and adds keys.
FIRST = ("--profile", "solo", "--script", str(TASKS), "--robot-id", "2")
SECOND = ("--profile", "husky", "--script", str(HELLO), "--robot-id", "3")


def first_deploy(name: str, tmp_path: Path) -> tuple[str, ...]:
    """A first deploy's options: the Husky's (SECOND), or an M100's (its app key too)."""
    if name == "m100":
        return m100(dji_app_key(tmp_path), "--script", HELLO)
    return SECOND


#: Where each case is killed: densely at the start (the lock, the manifest written before
#: any change), then ever more sparsely; points past a deploy's last change let it finish.
POINTS = (1, 2, 4, 8, 13, 19, 26, 44)


def kill_at_each(points: tuple[int, ...], roots: dict[int, Path], *args: str) -> dict[int, int]:
    """Run `fieldkit deploy ARGS --root ROOT` for each kill point at once (each with its own
    root), each killed after that many changes; their exit statuses."""
    procs = {
        step: fieldkit("deploy", *args, "--root", roots[step], env={CRASH_ENV: str(step)})
        for step in points
    }
    statuses = {}
    for step, proc in procs.items():
        _, err = proc.communicate(timeout=120)
        assert "Traceback" not in err, err
        statuses[step] = proc.returncode
        assert proc.returncode in (0, -signal.SIGKILL), err
    return statuses


def copies(template: Path | None, tmp_path: Path, points: tuple[int, ...]) -> dict[int, Path]:
    """A root per kill point: a copy of `template` (modes and links kept), or empty."""
    roots = {}
    for step in points:
        root = tmp_path / f"root{step}"
        if template is None:
            root.mkdir()
        else:
            shutil.copytree(template, root, symlinks=True)
        roots[step] = root
    return roots


@pytest.mark.parametrize("name", ["husky", "m100"])
def test_a_deploy_killed_anywhere_is_repaired_by_the_next(tmp_path: Path, name: str) -> None:
    """A first deploy onto an empty root, killed at each point, then deployed again: the
    tree a deploy never killed makes (an M100's app key file whole, 0600, or absent)."""
    args = first_deploy(name, tmp_path)
    reference = tmp_path / "reference"
    assert deploy(*args, "--root", reference).exit_code == 0
    want = listing(reference, mtimes=False)
    roots = copies(None, tmp_path, POINTS)
    statuses = kill_at_each(POINTS, roots, *args)
    # Killed at six points or more, and the last point past the end: the points span it.
    assert sum(s == -signal.SIGKILL for s in statuses.values()) >= 6, statuses
    assert statuses[POINTS[-1]] == 0, statuses
    key = reference / "etc/fieldkit/dji-app-key"
    for step, root in roots.items():
        for staged in [root / "etc/fieldkit/dji-app-key", *root.rglob(".dji-app-key.*")]:
            if staged.exists():  # never readable by others, never part-written
                assert staged.stat().st_mode & 0o077 == 0, f"{staged} at change {step}"
                assert staged.read_bytes() in (key.read_bytes(), b""), f"at change {step}"
        again = deploy(*args, "--root", root)
        assert again.exit_code == 0, f"after a kill at change {step}: {again.output}"
        assert listing(root, mtimes=False) == want, f"after a kill at change {step}"


def test_an_upgrade_killed_anywhere_is_repaired_by_the_next(tmp_path: Path, keys: Path) -> None:
    """A deploy over another (files replaced, others removed), killed at each point: every
    file is whole meanwhile (the old bytes or the new), and deploy again finishes the job."""
    template, reference = tmp_path / "template", tmp_path / "reference"
    assert deploy(*FIRST, "--root", template).exit_code == 0
    shutil.copytree(template, reference, symlinks=True)
    second = (*SECOND, "--keys", str(keys))
    assert deploy(*second, "--root", reference).exit_code == 0
    want = listing(reference, mtimes=False)
    roots = copies(template, tmp_path, POINTS)
    statuses = kill_at_each(POINTS, roots, *second)
    # Killed at six points or more, and the last point past the end: the points span it.
    assert sum(s == -signal.SIGKILL for s in statuses.values()) >= 6, statuses
    assert statuses[POINTS[-1]] == 0, statuses
    for step, root in roots.items():
        for path in root.rglob("*"):
            if not path.is_file() or path.is_symlink() or path.name.endswith(".fieldkit-tmp"):
                continue  # (a staged file, under its hidden name, is cleared by the next run)
            rel = path.relative_to(root)
            if path.name == "deploy-manifest.json":  # old, new, or the one between: whole
                Manifest.from_bytes(path.read_bytes(), path)
                continue
            whole = [p.read_bytes() for p in (template / rel, reference / rel) if p.is_file()]
            assert path.read_bytes() in whole, f"{rel} half-written at change {step}"
        again = deploy(*second, "--root", root)
        assert again.exit_code == 0, f"after a kill at change {step}: {again.output}"
        assert listing(root, mtimes=False) == want, f"after a kill at change {step}"
        assert not list(root.rglob("*.fieldkit-tmp"))


@pytest.mark.parametrize("name", ["solo", "m100"])
def test_an_uninstall_killed_anywhere_is_finished_by_the_next(tmp_path: Path, name: str) -> None:
    template, reference = tmp_path / "template", tmp_path / "reference"
    args = m100(dji_app_key(tmp_path), "--script", TASKS) if name == "m100" else FIRST
    assert deploy(*args, "--root", template).exit_code == 0
    shutil.copytree(template, reference, symlinks=True)
    assert deploy("--root", reference, "--uninstall", "--purge").exit_code == 0
    want = listing(reference, mtimes=False)
    points = (1, 3, 7, 12, 18)
    roots = copies(template, tmp_path, points)
    procs = {
        step: fieldkit("deploy", "--root", roots[step], "--uninstall", "--purge",
                       env={CRASH_ENV: str(step)})
        for step in points
    }  # fmt: skip
    killed = 0
    for step, proc in procs.items():
        _, err = proc.communicate(timeout=120)
        assert proc.returncode in (0, -signal.SIGKILL), err
        killed += proc.returncode == -signal.SIGKILL
        again = deploy("--root", roots[step], "--uninstall", "--purge")
        assert again.exit_code == 0, again.output
        assert listing(roots[step], mtimes=False) == want, f"after a kill at change {step}"
    assert killed >= 4


def test_two_deploys_at_once(tmp_path: Path) -> None:
    """While one deploy holds the lock (stopped after its first change), a second one, or an
    uninstall, fails at once naming the first one's pid, and changes nothing; the first one,
    continued, finishes its job."""
    root = tmp_path / "root"
    small = ("--profile", "solo", "--script", str(HELLO), "--robot-id", "2")
    assert deploy(*small, "--root", root).exit_code == 0
    first = fieldkit("deploy", *SECOND, "--root", root, env={CRASH_ENV: "1:STOP"})
    try:
        _, status = os.waitpid(first.pid, os.WUNTRACED)  # until it stops itself
        assert os.WIFSTOPPED(status), status
        during = listing(root)
        second = fieldkit("deploy", *small, "--root", root)
        _, err = second.communicate(timeout=60)
        assert second.returncode == 1, err
        assert errors(err) == [f"error: another fieldkit deploy is running (pid {first.pid})"]
        result = deploy("--root", root, "--uninstall")
        assert result.exit_code == 1
        assert f"another fieldkit deploy is running (pid {first.pid})" in result.stderr
        assert listing(root) == during
    finally:
        os.kill(first.pid, signal.SIGCONT)
        _, err = first.communicate(timeout=60)
    assert first.returncode == 0, err
    reference = tmp_path / "reference"
    assert deploy(*small, "--root", reference).exit_code == 0
    assert deploy(*SECOND, "--root", reference).exit_code == 0
    assert listing(root, mtimes=False) == listing(reference, mtimes=False)
