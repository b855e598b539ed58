"""The originator's pipeline: compile, test (an injected tester), release, signed patch."""

from __future__ import annotations

from pathlib import Path

import pytest

import bvm
from fieldkit.sim.trial import trial
from fieldkit.update.keys import init_keys, load_robot_keys, load_signing_key
from fieldkit.update.patch import open_update
from fieldkit.update.pipeline import BuildError, NothingToUpdate, build, make_patch_file
from fieldkit.update.release import Release

V1 = "function init() { t = 0 }\nfunction step() { t = t + 1 }\n"
V2 = 'include "lib.bzz"\nfunction init() { t = 0 }\nfunction step() { t = t + helper() }\n'
LIB = "function helper() { return 2 }\n"
# Robot 2 divides by zero in step() at simulated second 2.
BROKEN = """function init() { t = 0 }
function step() {
  if (t == 20 and id == 2) { var x = 1 / 0 }
  t = t + 1
}
"""


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_a_script_that_compiles_and_passes_its_test_is_a_release(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", V2)
    write(tmp_path / "lib" / "lib.bzz", LIB)
    tested: list[bvm.Program] = []

    def tester(program: bvm.Program) -> list[str]:
        tested.append(program)
        return []

    release = build(script, [tmp_path / "lib"], test=tester)
    expected = Release.from_program(bvm.compile_file(script, [str(tmp_path / "lib")]))
    assert release == expected and release.bdb and release.bpos
    assert [p.bytecode for p in tested] == [release.bo]  # the tested program is the release


def test_a_compile_error_is_path_line_col_and_nothing_is_tested(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", "function step() {\n  x = (1 +\n}\n")
    tested: list[bvm.Program] = []

    def tester(program: bvm.Program) -> list[str]:
        tested.append(program)
        return []

    with pytest.raises(BuildError) as caught:
        build(script, test=tester)
    assert caught.value.step == "compile"
    assert str(caught.value).startswith(f"{script}:3:1: ")
    assert caught.value.problems == (str(caught.value),)
    assert tested == []


def test_a_missing_include_is_a_compile_error_naming_it(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", V2)
    with pytest.raises(BuildError, match="Can't find file 'lib.bzz'") as caught:
        build(script, test=lambda p: [])
    assert str(caught.value).startswith(f"{script}:1:1: ")


def test_a_failed_test_names_each_script_error(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", V1)
    problems = ["s.bzz:2:3: division by zero (robot 2)", "s.bzz:9:1: boom (robot 3)\n  in step"]
    with pytest.raises(BuildError) as caught:
        build(script, test=lambda p: problems)
    e = caught.value
    assert e.step == "test" and e.problems == tuple(problems)
    text = str(e)
    assert (
        text.startswith(f"{script}: the new version failed its trial") and "2 script errors" in text
    )
    assert "  - s.bzz:2:3: division by zero (robot 2)\n" in text
    assert "  - s.bzz:9:1: boom (robot 3)\n      in step\n" in text


def test_the_real_trial_refuses_an_error_at_second_2(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", BROKEN)
    with pytest.raises(BuildError) as caught:
        build(script, test=lambda p: trial(p, ["solo", "husky"]))
    assert caught.value.step == "test"
    assert [p.splitlines()[0] for p in caught.value.problems] == [
        f"{script}:3:40: division by zero (robot 2 of the {name} swarm, at 2.0 s simulated)"
        for name in ("solo", "husky")
    ]


def test_a_patch_takes_the_base_to_the_new_release(tmp_path: Path) -> None:
    init_keys(tmp_path / "keys")
    base = Release.from_program(bvm.compile_source(V1, "s.bzz"))
    write(tmp_path / "lib.bzz", LIB)
    new = build(write(tmp_path / "s.bzz", V2), [tmp_path], test=lambda p: [])
    data = make_patch_file(
        new,
        base,
        3,
        load_signing_key(tmp_path / "keys"),
        load_robot_keys(tmp_path / "keys").swarm_key,
    )
    header, result = open_update(
        data, base=base, keys=load_robot_keys(tmp_path / "keys"), current_version=2
    )
    assert result == new and header.version == 3
    assert header.base_hash == base.hash and header.result_hash == new.hash


def test_no_patch_when_the_bytecode_did_not_change(tmp_path: Path) -> None:
    init_keys(tmp_path / "keys")
    base = Release.from_program(bvm.compile_source(V1, "s.bzz"))
    commented = Release.from_program(bvm.compile_source("# a comment\n" + V1, "s.bzz"))
    assert commented.bdb != base.bdb  # only the debug info moved
    with pytest.raises(NothingToUpdate, match="nothing to update"):
        make_patch_file(
            commented,
            base,
            2,
            load_signing_key(tmp_path / "keys"),
            load_robot_keys(tmp_path / "keys").swarm_key,
        )
