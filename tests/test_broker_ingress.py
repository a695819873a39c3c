"""The broker's cheap ingress (issue #19, realtime): pose samples coalesced per vehicle and applied when the
geometry is read, as of their arrival time; keys parsed once; info and control queries in round-robin
lanes like the modems' tx; the vectorised positions of external vehicles equal the per-vehicle formula.

Fake Zenoh session of tests/test_edge.py; counts and values are asserted exactly, never wall time."""

from __future__ import annotations

import numpy as np
import pytest
from test_edge import FakeSample, FakeSession, _wait  # noqa: E402
from uwsimnet_gli import wire

from uwsimnet_zenoh.bus import broker as broker_mod
from uwsimnet_zenoh.bus.broker import POSE_RING, Broker
from uwsimnet_zenoh.bus.outbox import Latest
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.kernel.realtime import RealtimeClock
from uwsimnet_zenoh.mobility.trajectory import PoseTable
from uwsimnet_zenoh.scene.load import load_scene_text


def _scene(n: int) -> object:
    devs = "".join(f"""<vehicle><name>v{i}</name><poseSource>zenoh</poseSource><CustomCommsDevice>
      <dccommsId>m{i}</dccommsId><mac>{i + 1}</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>
      <bitrate>100000</bitrate><maxDistance>5000</maxDistance><intrinsicDelay>0</intrinsicDelay>
      </CustomCommsDevice></vehicle>""" for i in range(n))
    return load_scene_text(f"""<?xml version="1.0"?><UWSimScene><simulation><world>ing</world>
      <duration>60</duration></simulation>
      <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
      <vehicle><name>fixed</name><position>0 0 0</position></vehicle>
      {devs}</UWSimScene>""", "ing.xml")


class Rig:
    def __init__(self, n: int = 3) -> None:
        self.session = FakeSession()
        self.net = Network(_scene(n), flows=False)
        self.clock = RealtimeClock(self.net.sched, spin=0.0005)
        self.b = Broker(self.session, self.net, self.clock, publish_trace=False, clock_rate_hz=0)  # type: ignore[arg-type]
        self.b.start()

    def pose(self, name: str, p: list[float], v: list[float] | None = None) -> None:
        m = {"p": p} if v is None else {"p": p, "v": v}
        self.b._pose_sample(FakeSample(self.b.keys.pose(name), wire.pack(m)), self.clock.now(), self.clock.wall_epoch())

    def close(self) -> None:
        self.clock.stop()
        self.clock.join(5)
        self.b.close()


@pytest.fixture
def rig():
    made: list[Rig] = []

    def make(n: int = 3) -> Rig:
        r = Rig(n)
        made.append(r)
        return r
    yield make
    for r in made:
        r.close()


def test_latest_keeps_the_newest_sample_per_key_and_the_one_before_for_an_earlier_reader():
    q = Latest(capacity=2)
    assert q.offer("a", 1.0, b"a1") and q.offer("a", 2.0, b"a2") and q.offer("a", 3.0, b"a3")
    assert q.offer("b", 1.5, b"b1")
    assert not q.offer("c", 1.0, b"c1") and q.refused == 1          # a third distinct key: refused
    assert q.take(0.5) == []
    # at 2.5 the newest of a (3.0) came later: the one before it (2.0) applies, standing for a1 and a2
    assert sorted(q.take(2.5)) == [("a", 2, 2.0, b"a2"), ("b", 1, 1.5, b"b1")]
    assert q.take(10.0) == [("a", 1, 3.0, b"a3")] and len(q) == 0
    assert q.received == 5


def test_poses_are_coalesced_applied_at_their_arrival_and_counted(rig):
    r = rig()
    b, net = r.b, r.net
    assert not net.poses.known[net.poses.index["v0"]]
    for x in range(10):                               # ten samples before anything reads the geometry
        r.pose("v0", [float(x), 0.0, 0.0])
    r.pose("v1", [100.0, 0.0, 0.0], v=[1.0, 0.0, 0.0])
    r.pose("nosuch", [0.0, 0.0, 0.0])
    r.pose("nosuch", [0.0, 0.0, 0.0])
    r.pose("fixed", [5.0, 0.0, 0.0])
    stamp = b._poses_in._pending[b.keys.pose("v1")][0]
    t = stamp + 2.0
    pos = net.poses.positions(t)                      # the read applies them (PoseTable.pull)
    assert list(pos[net.poses.index["v0"]]) == [9.0, 0.0, 0.0]
    # v1 moves on with its velocity from its arrival time, not from when it was read
    assert pos[net.poses.index["v1"]][0] == 100.0 + 1.0 * (t - stamp)
    assert list(pos[net.poses.index["fixed"]]) == [0.0, 0.0, 0.0]     # the scene drives it
    c = b.counters
    assert (c["poses"], c["poses_superseded"], c["pose_unknown"], c["pose_ignored"]) == (2, 9, 2, 1)
    assert len(b._poses_in) == 0


def test_a_tx_sees_the_poses_that_arrived_before_it(rig):
    r = rig()
    b, net = r.b, r.net
    r.clock.start()
    r.pose("v0", [0.0, 0.0, 0.0])
    r.pose("v1", [100.0, 0.0, 0.0])
    b._on_tx_sample(FakeSample(b.keys.tx("m0"), wire.pack({"dst": 2, "data": b"hi", "tag": 7})))
    rx1 = r.session.pubs["uwsimnet/ing/modem/m1/rx"]
    _wait(lambda: len(rx1.puts) == 1)
    f = wire.decode_rx(rx1.puts[0][1])
    assert f.data == b"hi" and f.dist == pytest.approx(100.0)
    assert b.counters["nopose"] == 0 and net.modems["m0"].counters["tx"] == 1


class _Secs:
    def __init__(self, s: float) -> None:
        self.s = s

    def as_secs_f64(self) -> float:
        return self.s


class _Stamp:
    """A Zenoh timestamp: what a router stamps a sample with when it receives it (NTP64, Unix seconds)."""

    def __init__(self, unix: float) -> None:
        self.unix = unix

    def get_time_as_ntp64(self) -> _Secs:
        return _Secs(self.unix)


class _Ring:
    """A subscriber with a ring channel handler: try_recv() until None."""

    def __init__(self, samples: list) -> None:
        self.samples = list(samples)

    def try_recv(self) -> object:
        return self.samples.pop(0) if self.samples else None

    def undeclare(self) -> None:
        pass


def _sample(b: Broker, name: str, x: float, unix: float | None = None) -> FakeSample:
    s = FakeSample(b.keys.pose(name), wire.pack({"p": [x, 0.0, 0.0], "v": [1.0, 0.0, 0.0]}))
    s.timestamp = None if unix is None else _Stamp(unix)
    return s


def test_a_pose_is_stamped_with_its_arrival_at_the_router_within_the_take(rig):
    """The router's timestamp says when a sample arrived: its simulation time is that, kept between the
    previous take of the ring and now (a router on another machine may have another clock); no timestamp:
    now."""
    b = rig().b
    epoch, now = 1000.0, 50.0                        # simulation time 0 was Unix time 1000
    b._pose_taken = 40.0
    b._pose_sample(_sample(b, "v0", 1.0, unix=1000.0 + 47.25), now, epoch)
    b._pose_sample(_sample(b, "v1", 1.0, unix=1000.0 + 12.0), now, epoch)      # before the last take
    b._pose_sample(_sample(b, "v2", 1.0, unix=1000.0 + 99.0), now, epoch)      # in the future
    b._pose_sample(_sample(b, "v3", 1.0), now, epoch)
    stamps = {k.rsplit("/", 1)[1]: e[0] for k, e in b._poses_in._pending.items()}
    assert stamps == {"v0": 47.25, "v1": 40.0, "v2": 50.0, "v3": 50.0}


def test_reading_the_geometry_takes_the_whole_ring_and_applies_the_newest_per_vehicle(rig):
    r = rig(3)
    b, net = r.b, r.net
    t = r.clock.now()                        # (not started: time stands still)
    burst = [_sample(b, f"v{i % 3}", float(i)) for i in range(40)]
    b._pose_sub = _Ring(burst)
    pos = net.poses.positions(t + 1.0)       # a transmission's geometry: PoseTable.pull takes the ring
    assert not b._pose_sub.samples and b._poses_in.received == 40
    assert (b.counters["poses"], b.counters["poses_superseded"]) == (3, 37)
    last = max(i for i in range(40) if i % 3 == 0)      # v0's newest sample, stamped at t
    assert pos[net.poses.index["v0"]][0] == last + 1.0 * 1.0          # and moved on 1 s at 1 m/s
    assert b._pose_taken == t and b.counters["pose_ring_full"] == 0


def test_a_full_ring_is_counted_and_said(rig, caplog):
    b = rig(2).b
    b._pose_sub = _Ring([_sample(b, "v0", 0.0)] * POSE_RING)
    with caplog.at_level("WARNING", logger="uwsimnet.bus.broker"):
        b._pull_poses(b.clock.now())
    assert b.counters["pose_ring_full"] == 1
    assert any("older ones may have been lost" in m for m in caplog.messages)
    assert broker_mod.POSE_RING == POSE_RING


def test_keys_are_parsed_once(rig):
    b = rig().b
    key = b.keys.tx("m0")
    assert b._tx_dev(key) == "m0" and b._tx_keys[key] == "m0"
    assert b._tx_dev("uwsimnet/other/modem/m0/tx") is None
    assert b._pose_verdict(b.keys.pose("v2")) == ("v2", None)
    assert b._pose_verdict("uwsimnet/ing/pose/a/b") == (None, "pose_bad_key")
    assert b._pose_verdict(b.keys.pose("nosuch")) == ("nosuch", "pose_unknown")


class FakeQuery:
    def __init__(self, key: str, done: list) -> None:
        self.key_expr = _Ke(key)
        self.payload = None
        self.done = done

    def __enter__(self) -> FakeQuery:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def reply(self, key: str, payload: bytes) -> None:
        self.done.append(("ok", key))

    def reply_err(self, payload: bytes) -> None:
        self.done.append(("err", wire.unpack(payload, 1 << 20)["error"]))


class _Ke:
    def __init__(self, key: str) -> None:
        self.key = key

    def intersects(self, other: str) -> bool:
        return wire.intersects(self.key, other)

    def __str__(self) -> str:
        return self.key


def test_queries_wait_in_their_lane_and_a_full_lane_answers_busy(rig):
    """Info queries take one turn per round among the modems' tx lanes; beyond the lane's capacity a
    query is answered at once with an error instead of piling up in front of the engine."""
    r = rig()
    b = r.b
    b._info_lane.capacity = 5
    done: list = []
    for _ in range(8):                                    # the engine is not running yet: they wait
        b._on_info_query(FakeQuery(b.keys.info("m1"), done))
    assert done == [("err", "busy: 5 queries are waiting")] * 3 and len(b._info_lane) == 5
    r.clock.start()
    _wait(lambda: len(done) == 8)
    assert done[3:] == [("ok", b.keys.info("m1"))] * 5
    info = b.info("m1")
    assert info["kind"] == "sim" and info["id"] == "m1" and info["ingress"]["n"] == 0 and "edge" in info


def test_vectorised_positions_equal_the_per_vehicle_formula():
    rng = np.random.default_rng(3)
    names = [f"v{i}" for i in range(40)]
    pt = PoseTable(names)
    for i, n in enumerate(names):
        if i % 3:
            pt.set_external(n)
        else:
            pt.set_static(n, rng.normal(size=3))
    samples = {}
    for i, n in enumerate(names):
        if i % 3 and i % 5:                               # some external ones never get a sample
            p, v, t = rng.normal(size=3) * 100, rng.normal(size=3), float(rng.uniform(0, 5))
            pt.update(n, t, p, v)
            samples[i] = (p, v, t)
    for t in (0.0, 2.5, 7.0):
        pos = pt.positions(t)
        for i, (p, v, ts) in samples.items():
            assert list(pos[i]) == list(p + v * max(0.0, t - ts))      # the same doubles
        for i in range(0, 40, 3):
            assert list(pos[i]) == list(pt._pos[i])
