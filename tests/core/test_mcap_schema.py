"""ros2msg schema text and RIHS01 hashes, checked against the installed .msg/.json files."""

import json
import sys
from pathlib import Path

import pytest
from ambid.recording.ros2_schema import (DEFINITION_SEPARATOR, full_message_definition, load_message_schema,
                                       nested_type_names, normalize_type_name, read_type_hash, split_full_definition)
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

SHARE = Path(sys.prefix) / "share"
SEP = "=" * 80


@pytest.fixture(autouse=True)
def ament_prefix(monkeypatch):
    monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)


def msg_text(pkg, name):
    return (SHARE / pkg / "msg" / f"{name}.msg").read_text()


def json_hash(pkg, name):
    doc = json.loads((SHARE / pkg / "msg" / f"{name}.json").read_text())
    return {e["type_name"]: e["hash_string"] for e in doc["type_hashes"]}[f"{pkg}/msg/{name}"]


def test_separator_is_80_equals():
    assert DEFINITION_SEPARATOR == SEP


def test_float64_multiarray_text_matches_rosbag2_layout():
    # Built by hand from the files: root, then its one dependency, then that one's.
    expected = (
        msg_text("std_msgs", "Float64MultiArray")
        + f"\n{SEP}\nMSG: std_msgs/MultiArrayLayout\n"
        + msg_text("std_msgs", "MultiArrayLayout")
        + f"\n{SEP}\nMSG: std_msgs/MultiArrayDimension\n"
        + msg_text("std_msgs", "MultiArrayDimension")
    )
    schema = load_message_schema("std_msgs/msg/Float64MultiArray")
    assert schema.definition == expected
    assert schema.dependencies == ("std_msgs/MultiArrayLayout", "std_msgs/MultiArrayDimension")
    assert schema.type_hash == json_hash("std_msgs", "Float64MultiArray")
    assert schema.type_name == "std_msgs/msg/Float64MultiArray"


def test_primitive_only_types_have_no_dependencies():
    for pkg, name in [("std_msgs", "String"), ("builtin_interfaces", "Time")]:
        schema = load_message_schema(f"{pkg}/{name}")  # short form accepted too
        assert schema.definition == msg_text(pkg, name)
        assert schema.dependencies == ()
        assert schema.type_hash == json_hash(pkg, name)
        assert schema.type_hash.startswith("RIHS01_") and len(schema.type_hash) == 7 + 64


def test_read_type_hash_picks_the_root_entry_not_a_dependency():
    h = read_type_hash("std_msgs/msg/Float64MultiArray")
    doc = json.loads((SHARE / "std_msgs" / "msg" / "Float64MultiArray.json").read_text())
    others = [e["hash_string"] for e in doc["type_hashes"] if e["type_name"] != "std_msgs/msg/Float64MultiArray"]
    assert len(others) == 2 and h not in others


CUSTOM = {
    "my_pkg/msg/Block": (
        "# Block with Inner inside: comment lines name no type\n"
        "uint8 KIND_A=1  # constant\n"
        "int32 OFFSET = -3\n"
        "string<=8 label \"abc\"\n"
        "float64[<=16] values\n"
        "Inner[3] inners\n"
        "builtin_interfaces/Time stamp\n"
        "int32[] idx\n"
        "   \n"
        "bool flag true\n"
    ),
    "my_pkg/Inner": "Deep d\nstring[<=4] names\n",
    "my_pkg/msg/Deep": "builtin_interfaces/Time t\nuint16 k 7\n",
}


def test_array_defaults_and_bounded_strings_are_primitive():
    text = "int32[] idx [1, 2]\nstring<=5[<=3] s [\"a\"]\nwstring w\nfoo_msgs/Bar[] bars\nBaz z # x\n"
    assert nested_type_names(text, "p") == ["foo_msgs/Bar", "p/Baz"]


def test_custom_definitions_constants_defaults_bounds_and_same_package_types():
    assert nested_type_names(CUSTOM["my_pkg/msg/Block"], "my_pkg") == ["builtin_interfaces/Time", "my_pkg/Inner"]
    text, deps = full_message_definition("my_pkg/msg/Block", definitions=CUSTOM)
    # Depth first, sorted per level, Time (already seen) not repeated under Deep.
    assert deps == ("builtin_interfaces/Time", "my_pkg/Inner", "my_pkg/Deep")
    sections = split_full_definition(text)
    assert list(sections) == [None, "builtin_interfaces/Time", "my_pkg/Inner", "my_pkg/Deep"]
    assert sections[None] == CUSTOM["my_pkg/msg/Block"]
    assert sections["builtin_interfaces/Time"] == msg_text("builtin_interfaces", "Time")
    assert sections["my_pkg/Deep"] == CUSTOM["my_pkg/msg/Deep"]

    # mcap_ros2 parses it and round-trips a message through CDR.
    encode = serialize_dynamic("my_pkg/msg/Block", text)["my_pkg/msg/Block"]
    decode = generate_dynamic("my_pkg/msg/Block", text)["my_pkg/msg/Block"]
    msg = {
        "label": "xy",
        "values": [1.5, -2.0],
        "inners": [{"d": {"t": {"sec": 5, "nanosec": 6}, "k": 9}, "names": ["a"]}] * 3,
        "stamp": {"sec": -2, "nanosec": 300_000_000},
        "idx": [4],
        "flag": True,
    }
    out = decode(encode(msg))
    assert out.label == "xy" and list(out.values) == [1.5, -2.0]
    assert out.inners[2].d.t.nanosec == 6 and out.inners[0].names == ["a"]
    assert out.stamp.sec == -2 and out.stamp.nanosec == 300_000_000
    assert list(out.idx) == [4] and out.flag is True


def test_supplied_definition_overrides_and_hash_is_validated():
    s = load_message_schema("my_pkg/Deep", definitions=CUSTOM, type_hash="RIHS01_" + "ab" * 32)
    assert s.type_hash == "RIHS01_" + "ab" * 32 and s.type_name == "my_pkg/msg/Deep"
    assert load_message_schema("my_pkg/Deep", definitions=CUSTOM).type_hash == ""  # no .json installed
    with pytest.raises(ValueError, match="RIHS01_"):
        load_message_schema("my_pkg/Deep", definitions=CUSTOM, type_hash="abc")


def test_missing_and_malformed_types_give_clear_errors(monkeypatch):
    with pytest.raises(FileNotFoundError, match="nonexistent_pkg/msg/Foo"):
        load_message_schema("nonexistent_pkg/msg/Foo")
    with pytest.raises(FileNotFoundError, match="my_pkg/msg/Inner"):
        full_message_definition("my_pkg/Block", definitions={"my_pkg/Block": "Inner i\n"})
    with pytest.raises(ValueError, match="pkg/msg/Type"):
        normalize_type_name("String")
    with pytest.raises(ValueError, match="not a message type"):
        normalize_type_name("std_srvs/srv/Empty")
    with pytest.raises(ValueError, match="field type"):
        nested_type_names("a/b/c/d x\n", "p")
    monkeypatch.setenv("AMENT_PREFIX_PATH", "")
    with pytest.raises(FileNotFoundError, match="AMENT_PREFIX_PATH"):
        load_message_schema("std_msgs/msg/String")
