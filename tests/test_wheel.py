"""The wheel works off the repository: built, installed in a fresh venv, run from elsewhere.

The wheel is built from a copy of the source (so the checkout gets no build/ folder and no
stale build/lib can leak into it) with `python -m build --wheel`, and installed without its
dependencies into a venv that sees this test environment's site-packages through a `.pth`
file: nothing is downloaded, and the venv's own site-packages, which holds the wheel, comes
first. Every command then runs with the working directory outside the checkout.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: What the wheel is built from: the project, without environments, caches and outputs.
SKIP = shutil.ignore_patterns(
    ".venv", ".git", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", ".hypothesis",
    "tests", "docs", "bench", "sitl-run", "*.tsv",
)  # fmt: skip


def run(cmd: list[str], cwd: Path, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    """Run `cmd` in `cwd` with no PYTHONPATH, so only the installed fieldkit can be imported."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run(
        cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv holding the wheel of this checkout; its bin/ folder."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=SKIP)
    built = run([sys.executable, "-m", "build", "--wheel", "--outdir", str(tmp / "dist")], src)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-2000:]
    (wheel,) = (tmp / "dist").glob("fieldkit-*.whl")
    env = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env)], check=True)
    python = env / "bin" / "python"
    purelib = run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp
    )
    deps = [p for p in site.getsitepackages() if Path(p).is_dir()]
    (Path(purelib.stdout.strip()) / "test-deps.pth").write_text("\n".join(deps) + "\n")
    pip = [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps"]
    installed = run([*pip, "--no-index", str(wheel)], tmp)
    assert installed.returncode == 0, installed.stderr[-2000:]
    return env / "bin"


def test_the_wheel_carries_its_data_and_not_the_checkout(venv: Path, tmp_path: Path) -> None:
    """fieldkit, its profiles and its scripts are imported from the venv, not from ROOT."""
    probe = (
        "import fieldkit, fieldkit.resources as r, fieldkit.robot.profiles as p;"
        "print(fieldkit.__file__); print(r.script_dir()); print(' '.join(p.list_profiles()));"
        "print(r.find_script('task_allocation.bzz'))"
    )
    out = run([str(venv / "python"), "-c", probe], tmp_path)
    assert out.returncode == 0, out.stderr
    module, scripts, profiles, script = out.stdout.split("\n")[:4]
    for path in (module, scripts, script):
        assert Path(path).is_relative_to(venv.parent) and not Path(path).is_relative_to(ROOT)
    assert profiles.split() == ["husky", "m100", "solo", "spiri"]
    assert Path(script).is_file() and (Path(scripts) / "graphs" / "P.graph").is_file()


def test_sim_runs_the_bundled_task_allocation(venv: Path, tmp_path: Path) -> None:
    """`fieldkit sim run` of the shipped task allocation: exit 0, every robot without error."""
    where = run(
        [str(venv / "python"), "-c", "import fieldkit.resources as r; print(r.script_dir())"],
        tmp_path,
    )
    script = Path(where.stdout.strip()) / "task_allocation.bzz"
    cmd = [str(venv / "fieldkit"), "sim", "run", str(script), "--robots", "4", "--seconds", "8"]
    cmd += ["--command", "1:1:22", "--command", "3:1:900", "--out", "out"]
    done = run(cmd, tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["errors"] == [], summary["errors"]


def test_node_finds_the_solo_profile(venv: Path, tmp_path: Path) -> None:
    """`fieldkit node --profile solo` gets past the profile: it stops at the silent autopilot."""
    hello = tmp_path / "hello.bzz"
    hello.write_text("function init() {}\nfunction step() {}\nfunction destroy() {}\n")
    cmd = [str(venv / "fieldkit"), "node", "--profile", "solo", "--script", str(hello)]
    cmd += ["--autopilot", "udpin:127.0.0.1:0", "--connect-timeout", "0.5", "--robot-id", "1"]
    cmd += ["--radio", "none"]  # the profile's XBee is not plugged in here
    done = run(cmd, tmp_path)
    assert "unknown profile" not in done.stderr
    assert done.returncode == 1 and "heartbeat" in done.stderr.lower(), done.stderr


def test_the_recording_types_ship_as_package_data(venv: Path, tmp_path: Path) -> None:
    """The .msg files of fieldkit.record are in the wheel: the typestores build from them."""
    probe = (
        "import fieldkit.record.types as t; from importlib import resources;"
        "print(resources.files(t.MSGS_PACKAGE).joinpath('fieldkit_msgs/msg/Tick.msg'));"
        "print(' '.join(sorted(t.msg_definitions())));"
        "print(t.typestore(True).generate_msgdef(t.MAVLINK)[1])"
    )
    out = run([str(venv / "python"), "-c", probe], tmp_path)
    assert out.returncode == 0, out.stderr
    where, names, md5 = out.stdout.split("\n")[:3]
    assert Path(where).is_file() and not Path(where).is_relative_to(ROOT)
    shipped = sorted(
        f"{p.parent.parent.name}/msg/{p.stem}"
        for p in (ROOT / "fieldkit" / "record" / "msgs").glob("*/msg/*.msg")
    )
    assert "fieldkit_msgs/msg/Tick" in shipped and "mavros_msgs/msg/Mavlink" in shipped
    assert names.split() == shipped  # every .msg of the checkout, from the wheel
    assert md5 == "41093e1fd0f3eea1da2aa33a177e5ba6"


def test_deploy_stages_the_node_from_the_wheel(venv: Path, tmp_path: Path) -> None:
    """`fieldkit deploy` from the wheel: the systemd templates ship, the shipped example is
    found by name, and the unit runs this venv's interpreter (never a `fieldkit` on PATH)."""
    root = tmp_path / "root"
    cmd = [str(venv / "fieldkit"), "deploy", "--profile", "solo", "--root", str(root)]
    done = run([*cmd, "--script", "examples/hello.bzz", "--robot-id", "1"], tmp_path)
    assert done.returncode == 0, done.stderr
    unit = root / "etc/systemd/system/fieldkit-node.service"
    (exec_start,) = [
        line for line in unit.read_text().splitlines() if line.startswith("ExecStart=")
    ]
    argv = shlex.split(exec_start.removeprefix("ExecStart="))
    assert Path(argv[0]).is_absolute() and Path(argv[0]).parent == venv, argv
    assert argv[1:] == ["-m", "fieldkit", "node", "--config", "/etc/fieldkit/fieldkit.toml"]
    probe = "import fieldkit.resources as r; print(r.example_dir()); print(r.systemd_dir())"
    examples, templates = run([str(venv / "python"), "-c", probe], tmp_path).stdout.split()
    for shipped in (examples, templates):  # the wheel's own, not the checkout's
        assert Path(shipped).is_relative_to(venv.parent) and not Path(shipped).is_relative_to(ROOT)
    installed = root / "var/lib/fieldkit/script/hello.bzz"
    assert installed.read_bytes() == (Path(examples) / "hello.bzz").read_bytes()
    # This venv is under /tmp, which the service could not see: said (a staged root only).
    assert "PrivateTmp=yes" in done.stderr
    analyze = shutil.which("systemd-analyze")
    if analyze is not None:
        checked = run([analyze, "verify", "--man=no", str(unit)], tmp_path)
        assert checked.returncode == 0 and checked.stderr == "", checked.stderr
