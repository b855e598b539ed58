"""`fieldkit node --config FILE`: the [node] table, its checks, and the command line over it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fieldkit.node.config import NODE_KEYS, NodeConfigError, load_config, parse_config
from fieldkit.node.recording import new_flight_path, prune_flights


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "fieldkit.toml"
    path.write_text(text)
    return path


def test_every_node_option_has_a_key() -> None:
    """The config's keys are the command's options, underscores for dashes (`--set` is
    `set`, `--include` is `include`, and --config itself is not a key)."""
    from fieldkit.cli.node import node_cmd

    params = {name for name in node_cmd.__code__.co_varnames[: node_cmd.__code__.co_argcount]} - {
        "config"
    }
    assert {"sets" if k == "set" else k for k in NODE_KEYS} == params


def test_a_good_file_loads_with_paths_relative_to_it(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        '[node]\nprofile = "solo"\nrobot_id = 3\nscript = "s.bzz"\nkeys = "/etc/k"\n'
        'include = ["lib"]\nset = ["SHAPE=Y"]\nconnect_timeout = 5\n'
        '[record]\ndir = "bags"\nkeep_mb = 100\n',
    )
    config = load_config(path)
    assert config.node["robot_id"] == 3 and config.node["set"] == ["SHAPE=Y"]
    assert config.node["script"] == str(tmp_path / "s.bzz")
    assert config.node["keys"] == "/etc/k"  # absolute stays
    assert config.node["include"] == [str(tmp_path / "lib")]
    assert config.node["connect_timeout"] == 5.0
    assert config.record is not None and config.record.dir == tmp_path / "bags"
    assert (config.record.max_mb, config.record.keep_mb) == (2048.0, 100.0)


def test_every_problem_is_named_by_file_and_key_at_once(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        '[node]\nprofile = "solo"\nrobot_id = "3a"\nrecod = "x"\nsecurity = "maybe"\n'
        "seconds = -1\n[nodes]\n",
    )
    with pytest.raises(NodeConfigError) as e:
        load_config(path)
    problems = e.value.problems
    assert f'{path}: node.robot_id: must be an integer, got "3a"' in problems
    assert f"{path}: node.recod: unknown key (did you mean record?)" in problems
    assert any(p.startswith(f"{path}: node.security: must be one of") for p in problems)
    assert f"{path}: node.seconds: must be > 0, got -1" in problems
    assert any(p.startswith(f"{path}: nodes: unknown key (did you mean node?)") for p in problems)
    assert len(problems) == 5


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("[node]\nprofile = 3\n", "node.profile: must be a non-empty string, got 3"),
        ('node = "solo"\n', "node: must be a table ([node])"),
        ("[node]\nrobot_id = true\n", "node.robot_id: must be an integer, got True"),
        ('[node]\ninclude = "lib"\n', "node.include: must be a list of strings"),
        ("[node]\nseconds = nan\n", "node.seconds: must be a finite number, got nan"),
        ('[node]\nrecord = "a"\n[record]\ndir = "b"\n', "node.record: give one of"),
        ("[record]\nmax_mb = 3\n", "record.dir: missing"),
        ("[node\n", "invalid TOML"),
    ],
)
def test_a_bad_file_says_what_and_where(tmp_path: Path, text: str, problem: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(NodeConfigError) as e:
        load_config(path)
    assert str(e.value).startswith(f"{path}: ") and problem in str(e.value)


def test_a_file_that_is_not_text_or_not_there(tmp_path: Path) -> None:
    path = tmp_path / "x.toml"
    path.write_bytes(b"\xff\xfe[node]")
    with pytest.raises(NodeConfigError, match="not UTF-8"):
        load_config(path)
    with pytest.raises(NodeConfigError, match="cannot read"):
        load_config(tmp_path / "nope.toml")


FAST = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=300)

_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner),
    max_leaves=8,
)


@FAST
@given(
    st.dictionaries(
        st.sampled_from(["node", "record", "x"]),
        st.dictionaries(st.sampled_from([*NODE_KEYS, "dir", "max_mb", "zz"]), _values) | _values,
    )
)
def test_any_parsed_document_loads_or_lists_its_problems(data: dict[str, object]) -> None:
    """The decoder's fuzz: whatever TOML parses into, the file loads or every problem is a
    `source: key: problem` line; nothing else escapes."""
    try:
        parse_config(data, source="f.toml", base=Path("/base"))
    except NodeConfigError as e:
        assert e.problems and all(p.startswith("f.toml: ") for p in e.problems)


@FAST
@given(st.binary(max_size=200))
def test_any_bytes_load_or_raise_a_config_error(data: bytes) -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.toml"
        path.write_bytes(data)
        try:
            load_config(path)
        except NodeConfigError as e:
            assert str(e).startswith(f"{path}: ")


def test_a_new_flight_never_reuses_a_path(tmp_path: Path) -> None:
    first = new_flight_path(tmp_path, now=0.0)
    assert first.name == "flight-19700101T000000Z"
    first.mkdir()
    second = new_flight_path(tmp_path, now=0.0)
    assert second.name == "flight-19700101T000000Z-2"


def test_old_flights_go_first_and_the_last_one_stays(tmp_path: Path) -> None:
    import os

    for i in range(4):
        d = tmp_path / f"flight-{i}"
        d.mkdir()
        (d / "data.mcap").write_bytes(b"x" * 2**20)  # 1 MiB each
        os.utime(d, (1000 + i, 1000 + i))
    (tmp_path / "notes.txt").write_text("mine")  # not a flight: never touched
    removed = prune_flights(tmp_path, keep_mb=3, room_mb=1)
    assert [p.name for p in removed] == ["flight-0", "flight-1"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight-2", "flight-3", "notes.txt"]
    assert [p.name for p in prune_flights(tmp_path, keep_mb=0.5, room_mb=1)] == ["flight-2"]
    assert (tmp_path / "flight-3").is_dir()  # the most recent stays, whatever the cap


def test_the_command_line_overrides_the_file(tmp_path: Path) -> None:
    from fieldkit.cli.node import node_options

    path = write(
        tmp_path,
        '[node]\nprofile = "solo"\nrobot_id = 3\nset = ["A=1", "B=2"]\nseed = 4\n'
        'radio = "none"\n[record]\ndir = "bags"\nmax_mb = 10\n',
    )
    given = dict.fromkeys(NODE_KEYS)
    given |= {"robot_id": 5, "set": ["B=3"], "profile": None}
    o = node_options(given, path)
    assert (o.profile, o.robot_id, o.seed, o.radio) == ("solo", 5, 4, "none")
    assert o.sets == ["A=1", "B=2", "B=3"]  # the command line's come last: they win
    assert o.record is not None and o.record.parent == tmp_path / "bags"
    assert o.record.name.startswith("flight-") and o.record_max_mb == 10.0
    assert json.dumps(str(o.config)) == json.dumps(str(path))


KEY = "0123456789abcdef" * 4  # 64 hex digits, like a DJI app key


def test_the_dji_app_comes_from_the_config_and_never_shows(tmp_path: Path) -> None:
    key_file = tmp_path / "dji-app-key"
    key_file.write_text(KEY.upper() + "\n")
    key_file.chmod(0o600)
    config = tmp_path / "f.toml"
    config.write_text(
        '[node]\nprofile = "m100"\n[dji]\napp_id = 1012345\napp_key_file = "dji-app-key"\n'
    )
    app = load_config(config).dji
    assert app is not None and app.app_id == 1012345 and app.app_key == KEY.upper()
    assert KEY.upper() not in repr(app) and KEY.upper() not in repr(load_config(config))
    config.write_text(f'[node]\nprofile = "m100"\n[dji]\napp_id = 7\napp_key = "{KEY}"\n')
    assert load_config(config).dji == type(app)(7, KEY)
    config.write_text('[node]\nprofile = "solo"\n')
    assert load_config(config).dji is None


@pytest.mark.parametrize(
    ("dji", "problem"),
    [
        (f'app_key = "{KEY}"', "dji.app_id: missing"),
        (f'app_id = 0\napp_key = "{KEY}"', "dji.app_id: must be 1..4294967295"),
        ("app_id = 1", "dji: give one of app_key and app_key_file"),
        (f'app_id = 1\napp_key = "{KEY}"\napp_key_file = "k"', "give one of app_key and"),
        (f'app_id = 1\napp_key = "{KEY[:-1]}z"', "dji.app_key: the DJI app key must be"),
        (f'app_id = 1\napp_key = "{KEY[:-2]}"', "must be 64 hex digits"),
        ('app_id = 1\napp_key_file = "nothere"', "dji.app_key_file: "),
        ('app_id = 1\napp_kye = "x"', "dji.app_kye: unknown key (did you mean app_key?)"),
    ],
)
def test_a_bad_dji_table_says_what_and_never_the_key(
    tmp_path: Path, dji: str, problem: str
) -> None:
    config = tmp_path / "f.toml"
    config.write_text(f'[node]\nprofile = "m100"\n[dji]\n{dji}\n')
    with pytest.raises(NodeConfigError) as e:
        load_config(config)
    assert problem in str(e.value)
    assert KEY[:-2] not in str(e.value)


def test_a_dji_key_file_others_can_read_is_refused(tmp_path: Path) -> None:
    key_file = tmp_path / "k"
    key_file.write_text(KEY)
    key_file.chmod(0o644)
    config = tmp_path / "f.toml"
    config.write_text(f'[dji]\napp_id = 1\napp_key_file = "{key_file}"\n')
    with pytest.raises(NodeConfigError, match=r"readable by others \(mode 644\): chmod 600"):
        load_config(config)
