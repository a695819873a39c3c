"""The key space of DESIGN.md: builders, wildcards, parser (uwsimnet_gli/wire.py)."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st
from uwsimnet_gli.wire import Key, KeyNameError, Keys, check_chunk, is_chunk, modem_id, parse

K = Keys("lab")


def test_builders_match_the_design():
    assert K.pose("bluerov") == "uwsimnet/lab/pose/bluerov"
    assert K.tx("alpha-modem") == "uwsimnet/lab/modem/alpha-modem/tx"
    assert K.rx("alpha-modem") == "uwsimnet/lab/modem/alpha-modem/rx"
    assert K.status("a") == "uwsimnet/lab/modem/a/status"
    assert K.info("a") == "uwsimnet/lab/modem/a/info"
    assert K.driver("a", "sim") == "uwsimnet/lab/modem/a/driver/sim"
    assert K.driver("a", "real") == "uwsimnet/lab/modem/a/driver/real"
    assert K.trace(0) == "uwsimnet/lab/trace/0"
    assert K.clock == "uwsimnet/lab/clock"
    assert K.control("pause") == "uwsimnet/lab/control/pause"


def test_wildcards():
    assert K.tx_all == "uwsimnet/lab/modem/*/tx"
    assert K.pose_all == "uwsimnet/lab/pose/**"
    assert K.info_all == "uwsimnet/lab/modem/*/info"
    assert K.drivers() == "uwsimnet/lab/modem/*/driver/*"
    assert K.drivers("real") == "uwsimnet/lab/modem/*/driver/real"
    assert K.drivers("sim", "m1") == "uwsimnet/lab/modem/m1/driver/sim"
    assert K.control_all == "uwsimnet/lab/control/**"
    # every wildcard is a valid Zenoh key expression that matches the concrete keys it stands for
    for wild, concrete in ((K.tx_all, K.tx("x")), (K.pose_all, K.pose("v")), (K.info_all, K.info("x")),
                           (K.drivers(), K.driver("x", "real")), (K.trace_all, K.trace(3)),
                           (K.control_all, K.control("move"))):
        assert zenoh.KeyExpr(wild).includes(zenoh.KeyExpr(concrete))


@pytest.mark.parametrize("bad", ["", "a/b", "a*", "$x", "a?", "a#b", "a b", "tab\t", 3, None])
def test_bad_chunks_are_refused(bad):
    assert not is_chunk(bad)
    with pytest.raises(KeyNameError):
        check_chunk(bad, "name")


def test_bad_names_in_builders():
    with pytest.raises(KeyNameError):
        Keys("a/b")
    with pytest.raises(KeyNameError):
        K.tx("x/y")
    with pytest.raises(KeyNameError):
        K.driver("x", "fake")
    with pytest.raises(KeyNameError):
        K.drivers("bogus")


def test_parse():
    assert parse(K.tx("m")) == Key("lab", "modem", "m", "tx")
    assert parse(K.driver("m", "real")) == Key("lab", "modem", "m", "driver", "real")
    assert parse(K.pose("v1")) == Key("lab", "pose", "v1")
    assert parse(K.trace(2)) == Key("lab", "trace", "2")
    assert parse(K.clock) == Key("lab", "clock")
    assert parse(K.control("move")) == Key("lab", "control", "move")
    assert modem_id(K.tx("abc"), "tx") == "abc"
    assert modem_id(K.rx("abc"), "tx") is None


@pytest.mark.parametrize("key", [
    "", "uwsimnet", "uwsimnet/lab", "other/lab/clock", "uwsimnet/lab/modem/m", "uwsimnet/lab/modem/m/bogus",
    "uwsimnet/lab/modem/m/driver/other", "uwsimnet/lab/modem/m/driver", "uwsimnet/lab/pose/a/b",
    "uwsimnet/lab/clock/x", "uwsimnet/*/modem/m/tx", "uwsimnet/lab/modem/*/tx", "uwsimnet//clock",
    "uwsimnet/lab/unknown/x",
])
def test_parse_rejects(key):
    assert parse(key) is None


chunk = st.text(st.characters(blacklist_characters="/*$?#", blacklist_categories=("Zs", "Cc")), min_size=1,
                max_size=12).filter(lambda s: not any(c.isspace() for c in s))


@given(world=chunk, dev=chunk, leaf=st.sampled_from(["tx", "rx", "status", "info"]))
def test_roundtrip(world, dev, leaf):
    k = Keys(world)
    assert parse(k.modem(dev, leaf)) == Key(world, "modem", dev, leaf)
    assert parse(k.pose(dev)) == Key(world, "pose", dev)


@given(st.text(max_size=40))
def test_parse_never_raises(s):
    parse(s)


# -- the key-expression algebra deploy's rules are built with, against Zenoh's own ---------------------
_chunk = st.sampled_from(["a", "b", "*", "**"])
_kexpr = st.lists(_chunk, min_size=1, max_size=4).map(lambda cs: str(zenoh.KeyExpr.autocanonize("/".join(cs))))


@given(_kexpr, _kexpr)
def test_intersects_and_includes_are_zenohs(a, b):
    from uwsimnet_gli.wire import includes, intersects

    za, zb = zenoh.KeyExpr(a), zenoh.KeyExpr(b)
    assert intersects(a, b) == za.intersects(zb), (a, b)
    assert includes(a, b) == za.includes(zb), (a, b)


def test_keys_are_built_from_the_uses_templates():
    from uwsimnet_gli import wire

    assert K.key(wire.TX, "m") == K.tx("m")
    assert K.key(wire.POSE, vehicle="v") == K.pose("v")
    assert K.key(wire.VEHICLE_CMD, vehicle="v") == K.vehicle_cmd("v")
    assert wire.expand(wire.TX, ["a", "b"]) == ["modem/a/tx", "modem/b/tx"]
    assert wire.expand(wire.VEHICLE_CMD) == ["vehicle/*/cmd"]
    assert wire.expand(wire.DRIVER, ["a"], kind="real") == ["modem/a/driver/real"]
