"""fieldkit.toml's writer: whatever it writes, Python's own TOML reader reads back as given;
the node's config as deploy writes it."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fieldkit.deploy.config_file import (
    HEADER,
    Key,
    NodeConfig,
    TomlValue,
    node_config,
    render_toml,
    toml_value,
)

from .kit import TASKS, deploy

values = st.one_of(
    st.text(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=False, allow_infinity=False),
    st.booleans(),
    st.lists(st.text(), max_size=4),
)


@given(st.dictionaries(st.from_regex(r"[a-z_]{1,12}", fullmatch=True), values, max_size=6),
       st.text().filter(lambda c: all(ord(x) >= 0x20 and ord(x) != 0x7F for x in c)))  # fmt: skip
def test_what_is_written_reads_back(table: dict[str, TomlValue], comment: str) -> None:
    keys = [Key(name, value, comment) for name, value in table.items()]
    text = render_toml(HEADER, [("node", keys)])
    assert tomllib.loads(text) == {"node": table}


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (2.0, "2.0"),
        (1e300, "1e+300"),
        (True, "true"),
        (3, "3"),
        ('a "b" \\ c\n\x7f', '"a \\"b\\" \\\\ c\\n\\u007F"'),
        (["x", "y"], '["x", "y"]'),
    ],
)
def test_values_as_toml_writes_them(value: TomlValue, text: str) -> None:
    assert toml_value(value) == text


def test_what_toml_cannot_say_is_refused() -> None:
    with pytest.raises(ValueError, match="finite"):
        toml_value(math.inf)
    with pytest.raises(TypeError, match="cannot write"):
        toml_value([1, 2])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="control character"):
        render_toml(HEADER, [("node", [Key("a", 1, "bad\ncomment")])])


def test_the_node_config_names_only_what_was_given() -> None:
    bare = tomllib.loads(node_config(NodeConfig(profile="solo")))
    assert bare == {
        "node": {"profile": "solo", "state_dir": "/var/lib/fieldkit/state"},
        "record": {"dir": "/var/log/fieldkit", "max_mb": 2048, "keep_mb": 8192},
    }
    full = tomllib.loads(
        node_config(
            NodeConfig(
                "solo",
                7,
                "/dev/autopilot",
                "none",
                "/var/lib/fieldkit/script/a.bzz",
                keys=True,
                include=True,
            )  # fmt: skip
        )
    )["node"]
    assert full == {
        "profile": "solo",
        "robot_id": 7,
        "autopilot": "/dev/autopilot",
        "radio": "none",
        "state_dir": "/var/lib/fieldkit/state",
        "script": "/var/lib/fieldkit/script/a.bzz",
        "keys": "/etc/fieldkit/keys",
        "security": "signed",
        "include": ["/var/lib/fieldkit/script/include"],
    }


def test_the_nodes_loader_reads_it(tmp_path: Path, keys: Path) -> None:
    """`fieldkit node --config` reads what deploy writes, every key, as deploy meant it."""
    from fieldkit.node.config import load_config

    root = tmp_path / "root"
    result = deploy("--profile", "husky", "--root", root, "--robot-id", "3", "--keys", keys,
                    "--script", TASKS)  # fmt: skip
    assert result.exit_code == 0, result.output
    config = load_config(root / "etc/fieldkit/fieldkit.toml")
    assert dict(config.node) == {
        "profile": "husky",
        "robot_id": 3,
        "autopilot": "/dev/autopilot",
        "radio": "serial:///dev/xbee?baud=230400&api=2",
        "gps": "/dev/gps",
        "state_dir": "/var/lib/fieldkit/state",
        "script": "/var/lib/fieldkit/script/task_allocation.bzz",
        "keys": "/etc/fieldkit/keys",
        "security": "signed",
        "include": ["/var/lib/fieldkit/script/include"],
    }
    assert config.record is not None
    assert (str(config.record.dir), config.record.max_mb, config.record.keep_mb) == (
        "/var/log/fieldkit", 2048.0, 8192.0,
    )  # fmt: skip
