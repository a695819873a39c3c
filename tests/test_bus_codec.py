"""The msgpack codecs of the one wire (uwsimnet_gli/wire.py), with validation, and the client's records."""

from __future__ import annotations

import contextlib
import math

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from uwsimnet_gli import wire
from uwsimnet_gli.wire import CodecError


def test_tx_roundtrip():
    r = wire.decode_tx(wire.encode_tx(2, b"hello", tag=7))
    assert (r.dst, r.data, r.tag, r.flow) == (2, b"hello", 7, None)
    r = wire.decode_tx(wire.encode_tx(255, b"", flow="f1"))
    assert (r.dst, r.data, r.tag, r.flow) == (255, b"", None, "f1")


def test_the_kind_of_message_crosses_in_tx_and_rx():
    """kind/flag/ts/pid (docs/gli-protocol.md): what an S2C modem's receiver reports as RECVIM(flag) /
    RECVIMS / RECVPBM / RECV, passed from tx to rx unchanged; absent when the sender did not say."""
    for msg in ({"kind": "im", "flag": "ack", "pid": 0}, {"kind": "im", "flag": "noack"}, {"kind": "ims"},
                {"kind": "ims", "ts": 4294967295, "pid": 7}, {"kind": "pbm"}, {"kind": "burst", "pid": 3}):
        r = wire.decode_tx(wire.encode_tx(2, b"m", tag=1, msg=msg))
        assert r.msg == msg
        assert msgpack.unpackb(wire.encode_tx(2, b"m", msg=msg)) == {"dst": 2, "data": b"m", **msg}
        assert wire.decode_rx(wire.encode_rx(1, 2, b"m", 0, 0.0, 0.1, 10.0, r.msg)).msg == msg
    assert wire.decode_tx(wire.encode_tx(2, b"m")).msg is None
    assert wire.decode_rx(wire.encode_rx(1, 2, b"m", 0, 0.0, 0.1)).msg is None
    for bad in ({"kind": "fax"}, {"kind": "burst", "flag": "ack"}, {"kind": "im", "flag": "maybe"},
                {"kind": "im", "ts": 5}, {"kind": "ims", "ts": -1}, {"kind": "ims", "ts": 1 << 32},
                {"kind": "pbm", "pid": 8}, {"flag": "ack"}):
        with pytest.raises(CodecError) as e:
            wire.decode_tx(msgpack.packb({"dst": 2, "data": b"m", "tag": 5, **bad}))
        assert e.value.reason == "invalid" and e.value.tag == 5
        with pytest.raises(ValueError):
            wire.encode_tx(2, b"m", msg=bad)


def test_tx_ignores_unknown_keys_and_nil_tag():
    r = wire.decode_tx(msgpack.packb({"dst": 1, "data": b"x", "tag": None, "future": [1, 2]}))
    assert r.tag is None and r.data == b"x"


@pytest.mark.parametrize("msg, reason", [
    (b"", "malformed"),
    (b"\xc1", "malformed"),                                   # never-used msgpack byte
    (b"\x92\x01", "malformed"),                               # truncated array
    (msgpack.packb({"dst": 1, "data": b"x"}) + b"\x00", "malformed"),   # trailing bytes
    (b"\xa2\xff\xfe", "malformed"),                           # str that is not UTF-8
    (msgpack.packb([1, 2]), "invalid"),
    (msgpack.packb("text"), "invalid"),
    (msgpack.packb({"data": b"x"}), "invalid"),
    (msgpack.packb({"dst": "2", "data": b"x"}), "invalid"),
    (msgpack.packb({"dst": True, "data": b"x"}), "invalid"),
    (msgpack.packb({"dst": -1, "data": b"x"}), "invalid"),
    (msgpack.packb({"dst": 70000, "data": b"x"}), "invalid"),
    (msgpack.packb({"dst": 1.5, "data": b"x"}), "invalid"),
    (msgpack.packb({"dst": 1, "data": "text, not bin"}), "invalid"),
    (msgpack.packb({"dst": 1}), "invalid"),
    (msgpack.packb({"dst": 1, "data": b"x", "tag": "t"}), "invalid"),
    (msgpack.packb({"dst": 1, "data": b"x", "tag": 1.0}), "invalid"),
    (msgpack.packb({"dst": 1, "data": b"x", "flow": 3}), "invalid"),
    (msgpack.packb({"dst": 1, "data": msgpack.ExtType(5, b"z")}), "invalid"),
])
def test_tx_refusals(msg, reason):
    with pytest.raises(CodecError) as e:
        wire.decode_tx(msg)
    assert e.value.reason == reason


def test_tx_refusal_keeps_a_readable_tag():
    with pytest.raises(CodecError) as e:
        wire.decode_tx(msgpack.packb({"dst": "x", "data": b"", "tag": 42}))
    assert e.value.tag == 42


def test_tx_too_large_is_refused_before_decoding():
    big = wire.encode_tx(1, bytes(wire.MAX_TX_MESSAGE))
    with pytest.raises(CodecError) as e:
        wire.decode_tx(big)
    assert e.value.reason == "toolarge"
    assert wire.decode_tx(big, limit=len(big)).data == bytes(wire.MAX_TX_MESSAGE)


def test_deep_nesting_is_malformed_not_a_crash():
    with pytest.raises(CodecError):
        wire.decode_tx(b"\x91" * 5000 + b"\x00")


@settings(max_examples=300)
@given(st.binary(max_size=200))
def test_random_bytes_only_raise_codec_errors(raw):
    for dec in (wire.decode_tx, wire.decode_pose, wire.decode_status, wire.decode_rx, wire.decode_request):
        with contextlib.suppress(CodecError):
            dec(raw)


values = st.recursive(st.none() | st.booleans() | st.integers(-2**63, 2**64 - 1) | st.floats() | st.text(max_size=5)
                      | st.binary(max_size=5),
                      lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=4), c, max_size=4),
                      max_leaves=10)


@settings(max_examples=300)
@given(st.dictionaries(st.sampled_from(["dst", "data", "tag", "flow", "p", "v", "q", "t", "x"]), values,
                       max_size=6))
def test_wrong_types_only_raise_codec_errors(m):
    raw = msgpack.packb(m, use_bin_type=True)
    for dec in (wire.decode_tx, wire.decode_pose, wire.decode_request):
        try:
            dec(raw)
        except CodecError as e:
            assert e.reason in ("invalid", "malformed", "toolarge")


def test_rx_and_status_roundtrip():
    f = wire.decode_rx(wire.encode_rx(1, 2, b"abc", 5, 1.25, 1.5))
    assert (f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx) == (1, 2, b"abc", 5, 1.25, 1.5)
    raw = wire.encode_status(9, "dropped", "fifo", 3.0)
    assert msgpack.unpackb(raw) == {"tag": 9, "event": "dropped", "reason": "fifo", "t": 3.0}
    s = wire.decode_status(raw)
    assert (s.tag, s.event, s.reason, s.t) == (9, "dropped", "fifo", 3.0)
    assert list(msgpack.unpackb(wire.encode_rx(1, 2, b"", 0, 0, 0))) == ["src", "dst", "data", "seq", "t_tx", "t_rx"]


def test_pose():
    p = wire.decode_pose(wire.encode_pose((1, 2, 3), t=4.0, v=(0.5, 0, 0), q=(0, 0, 0, 1)))
    assert p.p == (1.0, 2.0, 3.0) and p.t == 4.0 and p.v == (0.5, 0.0, 0.0) and p.q == (0.0, 0.0, 0.0, 1.0)
    assert wire.decode_pose(msgpack.packb({"p": [1, 2, 3]})).v is None
    for bad in ({"p": [1, 2]}, {"p": [1, 2, float("nan")]}, {"p": [1, 2, "3"]}, {}, {"p": [1, 2, 3], "v": [1]},
                {"p": [1, 2, 3], "t": "now"}, {"p": [True, 2, 3]}, {"p": [1.0, float("inf"), 2.0]},
                {"p": [1.0, 2.0, 3.0], "v": [0.0, -float("inf"), 0.0]}, {"p": [1.0, 2.0, None]}):
        with pytest.raises(CodecError):
            wire.decode_pose(msgpack.packb(bad))
    # floats whose sum overflows are finite all the same (the all-float path falls back to the full check)
    assert wire.decode_pose(msgpack.packb({"p": [1e308, 1e308, 0.0]})).p == (1e308, 1e308, 0.0)


@given(st.lists(st.floats(width=64) | st.integers(-2**63, 2**63 - 1), min_size=3, max_size=3))
def test_a_pose_is_taken_exactly_when_its_three_numbers_are_finite(xs):
    raw = msgpack.packb({"p": xs})
    if all(math.isfinite(x) for x in xs):
        assert wire.decode_pose(raw).p == tuple(float(x) for x in xs)
    else:
        with pytest.raises(CodecError):
            wire.decode_pose(raw)


def test_request():
    assert wire.decode_request(None) == {} and wire.decode_request(b"") == {}
    assert wire.decode_request(wire.pack({"vehicle": "a"})) == {"vehicle": "a"}
    with pytest.raises(CodecError):
        wire.decode_request(wire.pack({1: 2}))


def test_encoders_refuse_what_the_decoders_would():
    with pytest.raises(ValueError, match="dst must be an address"):
        wire.encode_tx(70000, b"")
    with pytest.raises(ValueError, match="p must have 3 components"):
        wire.encode_pose((1, 2))


def test_client_records_read_the_wire_leniently():
    from uwsimnet_gli import records

    f = records.read_rx(wire.encode_rx(1, 2, b"d", 3, 0.5, 0.75), "m")
    assert (f.src, f.dst, f.data, f.seq, f.t_tx, f.t_rx, f.modem) == (1, 2, b"d", 3, 0.5, 0.75, "m")
    s = records.read_status(wire.encode_status(None, "queued", None, 1.0))
    assert (s.tag, s.event, s.reason, s.t) == (None, "queued", None, 1.0)
    assert records.read_rx(b"\xc1") is None and records.read_status(b"junk") is None
    assert records.read_map(wire.pack({"a": 1})) == {"a": 1} and records.read_map(b"\xc1") is None
