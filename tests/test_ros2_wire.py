"""rmw_zenoh's wire (uwsimnet_zenoh/ros2/wire.py) against rmw_zenoh's own facts.

The golden strings are rmw_zenoh's docs/design.md (ros2/rmw_zenoh, lines 144-156 data keys, 218-242
liveliness tokens); the attachment layout is design.md's Publishers section and attachment_helpers.cpp
(zenoh-ext serialization of int64, int64, std::array<uint8_t, 16>); the hashes are the RIHS01 strings of
the ros-jazzy-* wheels' share/<pkg>/msg/*.json (tests/ros2_golden.json) and of rosidl's generator for
the project's own .msg files.
"""

from __future__ import annotations

import contextlib
import json
import math
import struct
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from uwsimnet_zenoh.ros2 import wire as w

GOLDEN = json.loads((Path(__file__).parent / "ros2_golden.json").read_text())["messages"]
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
DEFAULT_QOS = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, 42)


# -- golden strings from rmw_zenoh's design.md ------------------------------------------------------
def test_data_keys_of_the_design_document():
    assert w.data_key(0, w.fully_qualified("chatter"), "std_msgs/msg/String", STRING_HASH) == \
        "0/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH                                   # design.md:144
    assert w.data_key(0, w.fully_qualified("chatter", "/robot1"), "std_msgs/msg/String", STRING_HASH) == \
        "0/robot1/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH                            # design.md:150
    assert w.data_key(2, "/add_two_ints", "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS_HASH) == \
        "2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/" + ADD_TWO_INTS_HASH          # design.md:156


def test_node_token_of_the_design_document():
    assert w.node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener") == \
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"                         # design.md:218


@pytest.mark.parametrize("zid,kind,node,topic,ros_type,h,depth,expected", [
    ("aac3178e146ba6f1fc6e6a4085e77f21", "MS", "listener", "/chatter", "std_msgs/msg/String", STRING_HASH, 10,
     "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
     + STRING_HASH + "/::,10:,:,:,,"),                                                             # design.md:224
    ("8b20917502ee955ac4476e0266340d5c", "MP", "talker", "/chatter", "std_msgs/msg/String", STRING_HASH, 7,
     "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
     + STRING_HASH + "/::,7:,:,:,,"),                                                              # design.md:230
    ("f9980ee0495eaafb3e38f0d19e2eae12", "SS", "add_two_ints_server", "/add_two_ints",
     "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS_HASH, 10,
     "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/%add_two_ints/"
     "example_interfaces::srv::dds_::AddTwoInts_/" + ADD_TWO_INTS_HASH + "/::,10:,:,:,,"),        # design.md:236
    ("e1dc8d1b45ae8717fce78689cc655685", "SC", "add_two_ints_client", "/add_two_ints",
     "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS_HASH, 10,
     "@ros2_lv/2/e1dc8d1b45ae8717fce78689cc655685/0/10/SC/%/%/add_two_ints_client/%add_two_ints/"
     "example_interfaces::srv::dds_::AddTwoInts_/" + ADD_TWO_INTS_HASH + "/::,10:,:,:,,"),        # design.md:242
])
def test_entity_tokens_of_the_design_document(zid, kind, node, topic, ros_type, h, depth, expected):
    qos = w.QoS(w.RELIABLE, w.VOLATILE, w.KEEP_LAST, depth)
    assert w.entity_token(2, zid, 0, 10, kind, node, topic, ros_type, h, qos, explicit_qos=False) == expected
    tok = w.parse_token(expected)
    assert (tok.domain, tok.zid, tok.node_id, tok.entity_id, tok.kind, tok.node, tok.topic) == \
        (2, zid, "0", "10", kind, node, topic)
    assert (tok.enclave, tok.namespace, tok.dds_type, tok.type_hash) == ("/", "/", w.dds_type(ros_type), h)
    assert tok.qos == qos                             # empty fields = rmw_zenoh's defaults


def test_explicit_qos_reads_back_as_the_same_qos():
    """Our tokens write reliability, durability, history and depth; rmw_zenoh's parser reads any number."""
    for q in (w.QoS(), DEFAULT_QOS, w.QoS(w.BEST_EFFORT, w.TRANSIENT_LOCAL, w.KEEP_ALL, 0)):
        assert w.parse_qos(q.keyexpr()) == q
        assert w.parse_qos(q.keyexpr(explicit=False)) == q
    assert w.QoS(w.RELIABLE, w.TRANSIENT_LOCAL, w.KEEP_LAST, 1).keyexpr() == "1:1:1,1:,:,:,,"
    assert DEFAULT_QOS.keyexpr(explicit=False) == "::,:,:,:,,"
    with pytest.raises(w.Ros2WireError):
        w.QoS(reliability=4)                          # BEST_AVAILABLE: Humble cannot read it, never written
    with pytest.raises(w.Ros2WireError):
        w.parse_qos("1:2:1")


def test_namespaced_nodes_and_topics_are_mangled():
    tok = w.entity_token(0, "ab12", 3, 4, "MP", "alpha_m", w.fully_qualified("alpha_m/rx", "/uwsimnet"),
                         "uwsimnet_msgs/msg/Frame", "RIHS01_x", w.QoS(), namespace="/uwsimnet")
    assert tok == ("@ros2_lv/0/ab12/3/4/MP/%/%uwsimnet/alpha_m/%uwsimnet%alpha_m%rx/"
                   "uwsimnet_msgs::msg::dds_::Frame_/RIHS01_x/1:2:1,10:,:,:,,")
    t = w.parse_token(tok)
    assert (t.namespace, t.topic) == ("/uwsimnet", "/uwsimnet/alpha_m/rx")
    assert len(tok.split("/")) == 13                  # every non-node token: all 13 parts, none empty


def test_parse_token_rejects_what_is_not_a_graph_token():
    for key in ("@ros2_lv/0/z/0/0/XX/%/%/n", "@ros2_lv/0/z/0/0/MP/%/%/n", "uwsimnet/lab/modem/a/tx",
                "@ros2_lv/x/z/0/0/NN/%/%/n", "@ros2_lv/0/z/0/0/MP/%/%/n/%t/T/H/bad-qos"):
        assert w.parse_token(key) is None


@pytest.mark.parametrize("bad", ["", "/", "9lives", "a b", "a//b", "ros-2"])
def test_invalid_ros_names_are_refused(bad):
    with pytest.raises(w.Ros2WireError):
        w.fully_qualified(bad)


def test_dds_type_names():
    assert w.dds_type("nav_msgs/msg/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    assert w.dds_type("nav_msgs/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    assert w.ros_type_of("tf2_msgs::msg::dds_::TFMessage_") == "tf2_msgs/msg/TFMessage"
    with pytest.raises(w.Ros2WireError):
        w.dds_type("Odometry")


# -- distros ---------------------------------------------------------------------------------------
def test_humble_keys_carry_no_type_hash():
    assert w.key_type_hash("humble", STRING_HASH) == "TypeHashNotSupported"
    for d in ("jazzy", "kilted", "lyrical", "rolling"):
        assert w.key_type_hash(d, STRING_HASH) == STRING_HASH
    with pytest.raises(w.Ros2WireError):
        w.check_distro("iron")


# -- the attachment --------------------------------------------------------------------------------
def test_attachment_is_rmw_zenohs_33_bytes():
    gid = bytes(range(16))
    a = w.encode_attachment(1, 1_700_000_000_123_456_789, gid)
    # design.md: 8 bytes seq (int64 LE), 8 bytes timestamp (ns, int64 LE), 1 byte gid length (16), 16 bytes gid
    assert a == struct.pack("<q", 1) + struct.pack("<q", 1_700_000_000_123_456_789) + b"\x10" + gid
    assert len(a) == w.ATTACHMENT_SIZE == 33
    assert w.decode_attachment(a) == w.Attachment(1, 1_700_000_000_123_456_789, gid)


@pytest.mark.parametrize("raw,reason", [(None, "no-attachment"), (b"", "attachment"), (b"\x00" * 32, "attachment"),
                                        (b"\x00" * 16 + b"\x18" + b"\x00" * 16, "attachment"),
                                        (b"\x00" * 77, "attachment")])   # 77: the labelled pre-0.2.4 form
def test_bad_attachments_are_refused_with_a_reason(raw, reason):
    with pytest.raises(w.Ros2WireError) as e:
        w.decode_attachment(raw)
    assert e.value.reason == reason


@given(st.integers(-2**63, 2**63 - 1), st.integers(-2**63, 2**63 - 1), st.binary(min_size=16, max_size=16))
def test_attachment_round_trip(seq, ts, gid):
    assert w.decode_attachment(w.encode_attachment(seq, ts, gid)) == w.Attachment(seq, ts, gid)


@given(st.binary(max_size=64))
def test_decode_attachment_never_raises_anything_else(raw):
    with contextlib.suppress(w.Ros2WireError):
        w.decode_attachment(raw)


# -- RIHS01 ----------------------------------------------------------------------------------------
def _defs() -> dict[str, w.MsgDef]:
    texts = {
        "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
        "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
        "std_msgs/msg/String": "string data\n",
        "rosgraph_msgs/msg/Clock": "builtin_interfaces/Time clock\n",
        "diagnostic_msgs/msg/KeyValue": "string key\nstring value\n",
    }
    root = Path(w.__file__).parent / "interfaces"
    for f in sorted(root.glob("*/msg/*.msg")):
        texts[f"{f.parent.parent.name}/msg/{f.stem}"] = f.read_text()
    return {k: w.parse_msg(k, v) for k, v in texts.items()}


@pytest.mark.parametrize("ros_type", ["std_msgs/msg/String", "rosgraph_msgs/msg/Clock", "uwsimnet_msgs/msg/Frame",
                                      "uwsimnet_msgs/msg/Transmit", "uwsimnet_msgs/msg/Status",
                                      "dmac2_interfaces/msg/DMACPayload"])
def test_rihs01_from_definitions_equals_rosidls(ros_type):
    """The hashes of the shipped .msg files are computed, and equal what rosidl's generator made of them."""
    assert w.rihs01(ros_type, _defs()) == GOLDEN[ros_type]["rihs01"]


def test_msg_parser_reads_constants_bounds_arrays_and_comments():
    d = w.parse_msg("p/msg/M", "uint8 A=1  # c\nstring<=8 s 'x#y'\nfloat64[3] f\nint32[<=4] b\nM2[] nested\n"
                               "Header h\nbyte o\nchar c\n")
    assert d.constants == (("uint8", "A", "1"),)
    assert [(f.name, f.type, f.container, f.size, f.string_bound) for f in d.fields] == [
        ("s", "string", "", 0, 8), ("f", "float64", "array", 3, 0), ("b", "int32", "bounded", 4, 0),
        ("nested", "p/msg/M2", "sequence", 0, 0), ("h", "std_msgs/msg/Header", "", 0, 0),
        ("o", "byte", "", 0, 0), ("c", "char", "", 0, 0)]
    with pytest.raises(w.Ros2WireError):
        w.parse_msg("p/msg/M", "uint8\n")


# -- frames ----------------------------------------------------------------------------------------
def test_enu_ned():
    assert w.enu_to_ned((1.0, 2.0, 3.0)) == (2.0, 1.0, -3.0)
    assert w.ned_to_enu(w.enu_to_ned((1.0, 2.0, 3.0))) == (1.0, 2.0, 3.0)
    # a FLU body facing east in ENU (identity) is a FRD body facing east in NED: yaw +90 deg about down
    q = w.enu_to_ned_q((0.0, 0.0, 0.0, 1.0))
    assert q == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    # facing north in ENU (yaw +90 about up) = facing north in NED (identity)
    assert w.enu_to_ned_q((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))) == pytest.approx((0, 0, 0, 1), abs=1e-12)


@given(st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(c * c for c in q) > 0.01))
def test_quaternion_conversion_is_its_own_inverse(q):
    n = math.sqrt(sum(c * c for c in q))
    q = tuple(c / n for c in q)
    back = w.ned_to_enu_q(w.enu_to_ned_q(q))
    assert back == pytest.approx(q, abs=1e-9) or back == pytest.approx(tuple(-c for c in q), abs=1e-9)


# -- std_msgs/String with raw bytes (Stonefish) -----------------------------------------------------
def test_string_cdr_matches_rclpy_and_keeps_raw_bytes():
    g = GOLDEN["std_msgs/msg/String"]
    assert w.encode_string_cdr(g["fields"]["data"].encode()).hex() == g["cdr_hex"]
    raw = bytes(range(256))
    assert w.decode_string_cdr(w.encode_string_cdr(raw)) == raw
    for bad in (b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00\x05\x00\x00\x00ab",
                b"\x00\x00\x00\x00\x01\x00\x00\x00\x00"):
        with pytest.raises(w.Ros2WireError):
            w.decode_string_cdr(bad)
