"""fieldkit.robot.profiles: the shipped profiles load; every broken variant says where, why."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from fieldkit.robot.profiles import (
    PROFILE_DIR,
    Profile,
    ProfileError,
    UsbIds,
    list_profiles,
    load_profile,
)

SHIPPED = ["husky", "m100", "solo", "spiri"]


def shipped_text(name: str) -> str:
    """The text of a shipped profile."""
    return (PROFILE_DIR / f"{name}.toml").read_text(encoding="utf-8")


def variant(tmp_path: Path, base: str, old: str, new: str, *more: tuple[str, str]) -> Path:
    """A copy of shipped profile `base` with `old` replaced by `new`, then each (old, new) of
    `more` in turn; every `old` must occur exactly once when its turn comes."""
    text = shipped_text(base)
    for old_text, new_text in ((old, new), *more):
        assert text.count(old_text) == 1, f"{old_text!r} must occur exactly once in {base}.toml"
        text = text.replace(old_text, new_text)
    path = tmp_path / f"{base}-variant.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_list_profiles() -> None:
    assert list_profiles() == SHIPPED


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_profiles_load(name: str) -> None:
    p = load_profile(name)
    assert isinstance(p, Profile)
    assert p.name == name
    assert p.path == PROFILE_DIR / f"{name}.toml"
    assert p.node.loop_rate_hz == 10.0
    assert p.radio.per_step_budget_bytes == 190
    assert p.radio.baud == 230400
    k = p.kinematics
    assert 0 < k.max_speed_mps <= 5.0  # conservative field limits
    assert k.max_accel_mps2 > 0 and k.hover_accuracy_m > 0
    assert p.battery.full_voltage > p.battery.empty_voltage > 0
    if p.is_ground:
        assert (k.max_climb_mps, k.max_descent_mps, k.takeoff_altitude_m) == (0.0, 0.0, 0.0)
    else:
        assert k.takeoff_altitude_m <= p.geofence.max_altitude_m


def test_shipped_values() -> None:
    solo, m100, spiri, husky = (load_profile(n) for n in ("solo", "m100", "spiri", "husky"))
    assert solo.autopilot.flavour == "ardupilot"
    assert (solo.autopilot.guided_mode, solo.autopilot.land_mode) == ("GUIDED", "LAND")
    assert m100.autopilot.flavour == "dji"
    assert spiri.autopilot.flavour == "px4"
    assert spiri.kinematics.max_speed_mps == 3.0
    assert husky.vehicle == "ground" and husky.is_ground
    assert husky.kinematics.max_speed_mps == 1.0 and husky.kinematics.max_accel_mps2 == 3.0
    assert husky.failsafe.on_script_error in ("stop", "hold")


def test_same_profile_by_path_and_by_name(tmp_path: Path) -> None:
    copy = tmp_path / "mine.toml"
    copy.write_text(shipped_text("solo"), encoding="utf-8")
    by_path = load_profile(copy)
    assert by_path.path == copy
    assert dataclasses.replace(by_path, path=None) == dataclasses.replace(
        load_profile("solo"), path=None
    )
    assert load_profile(str(copy)).name == "solo"


def test_profiles_are_frozen() -> None:
    p = load_profile("solo")
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.kinematics.max_speed_mps = 50.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        p.radio.id_map["0013A20040A1B2C3"] = 1  # type: ignore[index]


def test_error_names_the_shipped_file_relative_to_the_repo(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # A broken file inside the profile directory is reported as device_profiles/<name>.toml.
    d = tmp_path / "device_profiles"
    d.mkdir()
    (d / "solo.toml").write_text(
        shipped_text("solo").replace("max_speed_mps = 5.0", "max_speed_mps = -1"),
        encoding="utf-8",
    )
    monkeypatch.setattr("fieldkit.robot.profiles.PROFILE_DIR", d)
    with pytest.raises(ProfileError) as e:
        load_profile("solo")
    assert (
        str(e.value) == "device_profiles/solo.toml: kinematics.max_speed_mps: must be > 0, got -1"
    )


def test_unknown_name() -> None:
    with pytest.raises(ProfileError, match=r"nope: unknown profile \(known: husky, m100"):
        load_profile("nope")


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.toml"
    with pytest.raises(ProfileError, match=f"^{path}: cannot read"):
        load_profile(path)


def test_defaults_fill_optional_fields(tmp_path: Path) -> None:
    minimal = tmp_path / "minimal.toml"
    minimal.write_text(
        """
name = "tiny"
vehicle = "uav"
[kinematics]
max_speed_mps = 2
max_accel_mps2 = 1
max_climb_mps = 1
max_descent_mps = 1
takeoff_altitude_m = 2
hover_accuracy_m = 0.5
[autopilot]
flavour = "px4"
url = "udpin:0.0.0.0:14540"
[geofence]
max_altitude_m = 10
[battery]
full_voltage = 12.6
empty_voltage = 10.5
endurance_s = 600
[radio]
kind = "udp"
""",
        encoding="utf-8",
    )
    p = load_profile(minimal)
    assert p.kinematics.max_speed_mps == 2.0 and isinstance(p.kinematics.max_speed_mps, float)
    assert p.autopilot.guided_mode == "OFFBOARD" and p.autopilot.rtl_mode == "RTL"
    assert p.autopilot.baud == 57600
    assert p.node.loop_rate_hz == 10.0
    assert p.geofence.polygon == ()
    assert (p.failsafe.on_heartbeat_loss, p.failsafe.on_low_battery) == ("land", "rtl")
    assert p.failsafe.on_script_error == "hold"
    assert p.battery.capacity_wh is None
    assert (p.radio.port, p.radio.udp_port, p.radio.api_mode) == ("", 24580, 2)
    assert p.radio.per_step_budget_bytes == 190
    assert p.robot_id.source == "hostname" and p.robot_id.value is None
    assert p.description == ""


def test_ground_defaults(tmp_path: Path) -> None:
    path = variant(tmp_path, "husky", "[failsafe]\n", "[old_failsafe]\n")
    text = path.read_text(encoding="utf-8")
    start = text.index("[old_failsafe]")
    end = text.index("[battery]")
    path.write_text(text[:start] + text[end:], encoding="utf-8")
    p = load_profile(path)
    assert (p.failsafe.on_heartbeat_loss, p.failsafe.on_low_battery) == ("stop", "stop")
    assert p.autopilot.land_mode == "HOLD"
    assert p.geofence.max_altitude_m == 0.0


def test_polygon_and_id_map(tmp_path: Path) -> None:
    path = variant(
        tmp_path,
        "solo",
        "polygon = []",
        "polygon = [[45.50, -73.55], [45.51, -73.55], [45.51, -73.54], [45, -73]]",
    )
    text = path.read_text(encoding="utf-8").replace(
        "[radio.id_map]\n", '[radio.id_map]\n"0013a20040a1b2c3" = 3\n"0013A20040A1B2C4" = 4\n'
    )
    text = text.replace('source = "hostname"', 'source = "xbee"')
    path.write_text(text, encoding="utf-8")
    p = load_profile(path)
    assert p.geofence.polygon[0] == (45.50, -73.55)
    assert p.geofence.polygon[3] == (45.0, -73.0)
    assert dict(p.radio.id_map) == {"0013A20040A1B2C3": 3, "0013A20040A1B2C4": 4}
    assert p.robot_id.source == "xbee"


def test_config_robot_id(tmp_path: Path) -> None:
    path = variant(tmp_path, "solo", 'source = "hostname"', 'source = "config"\nvalue = 7')
    assert load_profile(path).robot_id.value == 7


# (base profile, text to replace, replacement, the whole expected message after "<file>: ")
BROKEN = [
    (
        "solo",
        "max_speed_mps = 5.0",
        "max_speed_mps = -1",
        "kinematics.max_speed_mps: must be > 0, got -1",
    ),
    (
        "solo",
        "max_accel_mps2 = 2.5",
        "max_accel_mps2 = 0",
        "kinematics.max_accel_mps2: must be > 0, got 0",
    ),
    (
        "solo",
        "max_speed_mps = 5.0",
        'max_speed_mps = "fast"',
        "kinematics.max_speed_mps: must be a number, got string 'fast'",
    ),
    (
        "solo",
        "max_speed_mps = 5.0",
        "max_speed_mps = true",
        "kinematics.max_speed_mps: must be a number, got boolean true",
    ),
    (
        "solo",
        "max_speed_mps = 5.0",
        "max_speed_mps = inf",
        "kinematics.max_speed_mps: must be finite, got inf",
    ),
    (
        "solo",
        "max_speed_mps = 5.0",
        "max_speed_mps = nan",
        "kinematics.max_speed_mps: must be finite, got nan",
    ),
    ("solo", "max_speed_mps = 5.0", "", "kinematics.max_speed_mps: missing required field"),
    (
        "solo",
        "takeoff_altitude_m = 5.0",
        "",
        "kinematics.takeoff_altitude_m: missing required field",
    ),
    (
        "solo",
        "takeoff_altitude_m = 5.0",
        "takeoff_altitude_m = 0",
        "kinematics.takeoff_altitude_m: must be > 0, got 0",
    ),
    (
        "solo",
        "takeoff_altitude_m = 5.0",
        "takeoff_altitude_m = 40",
        "geofence.max_altitude_m: must be >= kinematics.takeoff_altitude_m (40), got 30",
    ),
    ("solo", 'name = "solo"', "", "name: missing required field"),
    ("solo", 'name = "solo"', 'name = ""', "name: must not be empty"),
    (
        "solo",
        'vehicle = "uav"',
        'vehicle = "boat"',
        'vehicle: must be one of "uav", "ground", got \'boat\'',
    ),
    ("solo", 'name = "solo"', 'name = "solo"\ncolour = "red"', "colour: unknown field"),
    ("solo", "[radio]\n", "[radio]\nbad_key = 1\n", "radio.bad_key: unknown field"),
    (
        "solo",
        'flavour = "ardupilot"',
        'flavour = "betaflight"',
        'autopilot.flavour: must be one of "ardupilot", "px4", "dji", "clearpath", '
        "got 'betaflight'",
    ),
    ("solo", 'url = "udpin:0.0.0.0:14550"', "", "autopilot.url: missing required field"),
    (
        "solo",
        "baud = 57600",
        "baud = 57600.0",
        "autopilot.baud: must be an integer, got float 57600.0",
    ),
    (
        "solo",
        "heartbeat_timeout_s = 3.0",
        "heartbeat_timeout_s = -3",
        "autopilot.heartbeat_timeout_s: must be > 0, got -3",
    ),
    (
        "solo",
        'guided_mode = "GUIDED"',
        'guided_mode = ""',
        "autopilot.guided_mode: must not be empty",
    ),
    ("solo", "loop_rate_hz = 10", "loop_rate_hz = 0", "node.loop_rate_hz: must be > 0, got 0"),
    ("solo", "max_altitude_m = 30.0", "", "geofence.max_altitude_m: missing required field"),
    (
        "solo",
        "polygon = []",
        "polygon = [[45.5, -73.5], [45.6, -73.5]]",
        "geofence.polygon: needs at least 3 corners (or none), got 2",
    ),
    (
        "solo",
        "polygon = []",
        "polygon = [[45.5, -73.5], [45.6, -73.5], [45.7, -73.5]]",
        "geofence.polygon: corners enclose no area",
    ),
    (
        "solo",
        "polygon = []",
        "polygon = [[95.0, -73.5], [45.6, -73.5], [45.7, -73.4]]",
        "geofence.polygon[0][0]: latitude must be in -90..90, got 95",
    ),
    (
        "solo",
        "polygon = []",
        "polygon = [[45.5, -73.5], [45.6, -73.5], [45.7]]",
        "geofence.polygon[2]: must be a [lat, lon] pair, got an array",
    ),
    (
        "solo",
        "polygon = []",
        'polygon = "none"',
        "geofence.polygon: must be an array of [lat, lon] pairs, got string 'none'",
    ),
    (
        "solo",
        'on_script_error = "hold"',
        'on_script_error = "panic"',
        'failsafe.on_script_error: must be one of "hold", "land", "rtl", "stop", got \'panic\'',
    ),
    (
        "solo",
        "low_battery_percent = 25",
        "low_battery_percent = 100",
        "failsafe.low_battery_percent: must be < 100, got 100",
    ),
    (
        "solo",
        "empty_voltage = 14.0",
        "empty_voltage = 17.0",
        "battery.empty_voltage: must be < battery.full_voltage (16.8), got 17",
    ),
    ("solo", "endurance_s = 1080", "", "battery.endurance_s: missing required field"),
    (
        "solo",
        'kind = "xbee"',
        'kind = "lora"',
        'radio.kind: must be one of "xbee", "udp", got \'lora\'',
    ),
    (
        "solo",
        'port = "/dev/ttyUSB0"',
        "",
        'radio.port: required when kind is "xbee" (the XBee serial device)',
    ),
    ("solo", "api_mode = 2", "api_mode = 3", "radio.api_mode: must be in 1..2, got 3"),
    (
        "solo",
        "udp_port = 24580",
        "udp_port = 70000",
        "radio.udp_port: must be in 1..65535, got 70000",
    ),
    (
        "solo",
        "[radio.id_map]\n",
        '[radio.id_map]\n"0013A200" = 1\n',
        "radio.id_map.0013A200: must be an XBee 64-bit serial (16 hex digits)",
    ),
    (
        "solo",
        "[radio.id_map]\n",
        '[radio.id_map]\n"0013A20040A1B2C3" = 300\n',
        "radio.id_map.0013A20040A1B2C3: must be in 0..255, got 300",
    ),
    (
        "solo",
        "[radio.id_map]\n",
        '[radio.id_map]\n"0013A20040A1B2C3" = 1\n"0013A20040A1B2C4" = 1\n',
        "radio.id_map.0013A20040A1B2C4: robot id 1 is already given to 0013A20040A1B2C3",
    ),
    (
        "solo",
        'source = "hostname"',
        'source = "dns"',
        'robot_id.source: must be one of "config", "hostname", "xbee", got \'dns\'',
    ),
    ("solo", 'source = "hostname"', 'source = "config"', "robot_id.value: missing required field"),
    (
        "solo",
        'source = "hostname"',
        'source = "hostname"\nvalue = 3',
        "robot_id.value: only used with source = \"config\", not 'hostname'",
    ),
    (
        "solo",
        'source = "hostname"',
        'source = "xbee"',
        'robot_id.source: "xbee" needs radio.id_map to list the XBee serials',
    ),
    # Ground robot rules.
    (
        "husky",
        'on_script_error = "stop"',
        'on_script_error = "land"',
        'failsafe.on_script_error: ground robots cannot "land"; use "stop" or "hold"',
    ),
    (
        "husky",
        'on_low_battery = "stop"',
        'on_low_battery = "rtl"',
        'failsafe.on_low_battery: ground robots cannot "rtl"; use "stop" or "hold"',
    ),
    (
        "husky",
        "hover_accuracy_m = 0.5",
        "hover_accuracy_m = 0.5\ntakeoff_altitude_m = 5",
        "kinematics.takeoff_altitude_m: ground robots do not fly; use 0 or leave it out, got 5",
    ),
    (
        "husky",
        "hover_accuracy_m = 0.5",
        "hover_accuracy_m = 0.5\nmax_climb_mps = 1",
        "kinematics.max_climb_mps: ground robots do not fly; use 0 or leave it out, got 1",
    ),
    (
        "husky",
        "polygon = []",
        "polygon = []\nmax_altitude_m = 30",
        "geofence.max_altitude_m: ground robots do not fly; use 0 or leave it out, got 30",
    ),
]


# Broken in more than one place, or by more than one edit: every problem is reported, one line
# each, in the loader's order. (base profile, the (old, new) edits made in turn, the messages.)
BROKEN_SEVERAL: list[tuple[str, list[tuple[str, str]], list[str]]] = [
    (
        "solo",
        [("[battery]\n", "[batery]\n")],
        ["batery: unknown field", "battery: missing required table"],
    ),
    (
        "solo",
        [("[geofence]\n", "[old_geofence]\n")],  # only ground robots may leave it out
        ["old_geofence: unknown field", "geofence: missing required table"],
    ),
    (
        "solo",
        [('kind = "xbee"', 'kind = "udp"'), ('source = "hostname"', 'source = "xbee"')],
        ['robot_id.source: "xbee" needs radio.kind = "xbee", not \'udp\''],
    ),
    (
        "solo",
        [
            ("max_speed_mps = 5.0", "max_speed_mps = -1\nwings = 2"),
            ("api_mode = 2", "api_mode = 0"),
        ],
        [
            "kinematics.wings: unknown field",
            "kinematics.max_speed_mps: must be > 0, got -1",
            "radio.api_mode: must be in 1..2, got 0",
        ],
    ),
]
CASES = [(base, [(old, new)], [expected]) for base, old, new, expected in BROKEN] + BROKEN_SEVERAL


@pytest.mark.parametrize(
    ("base", "edits", "expected"), CASES, ids=[" / ".join(case[2]) for case in CASES]
)
def test_broken_variants(
    tmp_path: Path, base: str, edits: list[tuple[str, str]], expected: list[str]
) -> None:
    """Each problem is one `<file>: <dotted field>: <problem>` line, and there is no other."""
    (old, new), *more = edits
    path = variant(tmp_path, base, old, new, *more)
    with pytest.raises(ProfileError) as e:
        load_profile(path)
    want = tuple(f"{path}: {message}" for message in expected)
    assert e.value.problems == want
    assert str(e.value) == "\n".join(want)
    assert isinstance(e.value, ValueError)


def test_ground_profile_accepts_explicit_zeros_and_hold(tmp_path: Path) -> None:
    path = variant(
        tmp_path,
        "husky",
        'on_script_error = "stop"',
        'on_script_error = "hold"\n[kinematics_extra]',
    )
    # "[kinematics_extra]" is there to prove unknown tables are caught; remove it here.
    path.write_text(path.read_text().replace("\n[kinematics_extra]", ""), encoding="utf-8")
    text = path.read_text().replace(
        "hover_accuracy_m = 0.5",
        "hover_accuracy_m = 0.5\ntakeoff_altitude_m = 0\nmax_climb_mps = 0.0",
    )
    path.write_text(text, encoding="utf-8")
    p = load_profile(path)
    assert p.failsafe.on_script_error == "hold"
    assert p.kinematics.takeoff_altitude_m == 0.0


def test_ground_geofence_table_is_optional(tmp_path: Path) -> None:
    # A UAV without one is in BROKEN_SEVERAL.
    husky = variant(tmp_path, "husky", "[geofence]\npolygon = []", "")
    assert load_profile(husky).geofence.polygon == ()


def test_table_of_the_wrong_type(tmp_path: Path) -> None:
    path = variant(tmp_path, "solo", 'description = "', 'battery = 3\ndescription = "')
    with pytest.raises(ProfileError) as e:
        load_profile(path)
    # TOML itself refuses a key defined twice (battery = 3, then [battery]).
    assert "invalid TOML" in str(e.value)
    path = tmp_path / "flat.toml"
    path.write_text('name = "x"\nvehicle = "uav"\nkinematics = 3\n', encoding="utf-8")
    with pytest.raises(ProfileError) as e:
        load_profile(path)
    assert f"{path}: kinematics: must be a table, got integer 3" in e.value.problems
    assert f"{path}: autopilot: missing required table" in e.value.problems


def test_invalid_toml_gives_line_and_column(tmp_path: Path) -> None:
    path = variant(tmp_path, "solo", "max_speed_mps = 5.0", "max_speed_mps = = 5.0")
    with pytest.raises(ProfileError) as e:
        load_profile(path)
    lines = shipped_text("solo").splitlines()
    line = next(i for i, x in enumerate(lines) if x.startswith("max_speed_mps"))
    msg = str(e.value)
    assert msg.startswith(f"{path}: invalid TOML: ")
    assert f"line {line + 1}, column 17" in msg


def test_radio_security_is_optional_and_checked(tmp_path: Path) -> None:
    assert load_profile("solo").radio.security is None  # signed with keys, none without
    path = variant(
        tmp_path,
        "solo",
        "per_step_budget_bytes = 190",
        'per_step_budget_bytes = 190\nsecurity = "none"',
    )
    assert load_profile(path).radio.security == "none"
    path = variant(
        tmp_path,
        "solo",
        "per_step_budget_bytes = 190",
        'per_step_budget_bytes = 190\nsecurity = "maybe"',
    )
    with pytest.raises(ProfileError, match="radio.security"):
        load_profile(path)


def test_a_profile_that_asks_for_signed_bundles_needs_keys(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app

    path = variant(
        tmp_path,
        "solo",
        "per_step_budget_bytes = 190",
        'per_step_budget_bytes = 190\nsecurity = "signed"',
    )
    result = CliRunner().invoke(
        app,
        ["sim", "run", "task_allocation.bzz", "--robots", "2", "--seconds", "1",
         "--profile", str(path), "--out", str(tmp_path / "run")],
    )  # fmt: skip
    assert result.exit_code == 1
    assert "profile's [radio] security" in result.stderr and "--keys" in result.stderr


def test_usb_ids_are_optional_and_lower_cased(tmp_path: Path) -> None:
    """[usb] gives the serial adapters' ids for deploy's udev rules; without it, none."""
    husky = load_profile("husky").usb
    assert (husky.autopilot, husky.radio, husky.gps) == ("067b:2303", "0403:6015", "1546:01a8")
    assert load_profile("solo").usb.radio == "0403:6015"
    assert load_profile("solo").usb.autopilot is None  # the Solo's autopilot is on WiFi
    path = variant(tmp_path, "spiri", 'radio = "0403:6015"', 'radio = "0403:60AB"')
    assert load_profile(path).usb.radio == "0403:60ab"
    path = variant(tmp_path, "spiri", "[usb]\n", "[old_usb]\n")
    with pytest.raises(ProfileError):  # (old_usb.radio is an unknown table)
        load_profile(path)
    text = shipped_text("spiri")
    bare = tmp_path / "bare.toml"
    bare.write_text(text[: text.index("[usb]")], encoding="utf-8")
    assert load_profile(bare).usb == UsbIds(autopilot=None, radio=None)
    # A GPS receiver's adapter only where the profile has a receiver of its own ([gps]).
    path = variant(
        tmp_path, "spiri", 'radio = "0403:6015"', 'radio = "0403:6015"\ngps = "1546:01a8"'
    )
    with pytest.raises(ProfileError, match=r"usb\.gps: names a GPS receiver's adapter, and the "
                       r"profile has no \[gps\] table"):  # fmt: skip
        load_profile(path)
    path = variant(tmp_path, "husky", 'gps = "1546:01a8"', 'gps = "u-blox"')
    with pytest.raises(ProfileError, match=r"usb\.gps: must be VENDOR:PRODUCT"):
        load_profile(path)


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ('"0403-6015"', "usb.radio: must be VENDOR:PRODUCT, four hex digits each as lsusb "
         "prints them (e.g. \"0403:6015\"), got '0403-6015'"),
        ('"403:6015"', "usb.radio: must be VENDOR:PRODUCT"),
        ('"0403:60156"', "usb.radio: must be VENDOR:PRODUCT"),
        ('"04g3:6015"', "usb.radio: must be VENDOR:PRODUCT"),
        ("4036015", "usb.radio: must be a string, got integer 4036015"),
    ],
)  # fmt: skip
def test_a_bad_usb_id_names_file_and_field(tmp_path: Path, value: str, expected: str) -> None:
    path = variant(tmp_path, "spiri", 'radio = "0403:6015"', f"radio = {value}",
                   ("[usb]\n", "[usb]\nserial = 1\n"))  # fmt: skip
    with pytest.raises(ProfileError) as e:
        load_profile(path)
    # Every problem of the table at once: the unknown field too.
    assert e.value.problems[0] == f"{path}: usb.serial: unknown field"
    assert e.value.problems[1].startswith(f"{path}: {expected}"), e.value.problems


def test_the_stop_action_defaults_by_vehicle_and_is_checked(tmp_path: Path) -> None:
    """`failsafe.on_stop`: hold for a UAV, stop for a ground robot; a ground robot cannot
    land, and rtl is no stop action (the node must not fly off when told to stop)."""
    assert load_profile("solo").failsafe.on_stop == "hold"
    assert load_profile("husky").failsafe.on_stop == "stop"
    for name, value, problem in [
        ("husky", "land", 'must be one of "stop", "hold"'),
        ("solo", "rtl", 'must be one of "hold", "land"'),
    ]:
        path = load_profile(name).path
        assert path is not None
        mine = tmp_path / f"{name}.toml"
        mine.write_text(path.read_text().replace("[failsafe]", f'[failsafe]\non_stop = "{value}"'))
        with pytest.raises(ProfileError, match=f"failsafe.on_stop: {problem}"):
            load_profile(mine)
