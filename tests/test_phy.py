"""The physical layer against its formulas: delay, range, loss statistics, collisions, duplex, FIFO."""

from __future__ import annotations

import io
import math

import pytest
from conftest import Recorded, device, scene, vehicle

from uwsimnet_zenoh.scene.model import Channel, Flow, Waypoint
from uwsimnet_zenoh.trace.events import JsonlSink

C = 1500.0  # m/s in the default test channel


def at(rec: Recorded, t: float, dev: str, dst: int, size: int, **kw) -> None:
    rec.net.sched.at(t, lambda: rec.net.modems[dev].send(dst, size, **kw))


def test_end_to_end_delay_is_the_formula_exactly():
    ch = Channel(id=0, prop_s_per_m=1 / C, min_prop_s=0.01)
    a = device("a", 1, bitrate=1000, header_bytes=5, intrinsic_tx_s=0.002, intrinsic_rx_s=0.003)
    b = device("b", 2, bitrate=1000, header_bytes=5, intrinsic_rx_s=0.003)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (90, 120, 0), b)], channels=[ch]))
    at(rec, 1.0, "a", 2, 20)
    rec.run()
    (tx,) = rec.ev("tx")
    (rx,) = rec.ev("rx")
    assert tx["t"] == pytest.approx(1.002, abs=1e-9)
    # 150 m: 0.01 + 0.1 s propagation; 25 B at 1000 bps = 0.2 s; rx intrinsic 0.003 s
    assert rx["t"] == pytest.approx(1.002 + 0.01 + 150 / C + 0.2 + 0.003, abs=1e-9)
    assert rx["dist"] == 150.0 and rx["size"] == 25 and rx["dev"] == "b"


def test_delay_uses_the_distance_at_transmission_start():
    traj = (Waypoint(t=0, x=0, y=0, z=0), Waypoint(t=100, x=1500, y=0, z=0))  # 15 m/s away
    a = device("a", 1, bitrate=8000)
    b = device("b", 2, bitrate=8000)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (0, 0, 0), b, trajectory=traj)],
                         duration=100))
    for t in (10.0, 20.0, 40.0):
        at(rec, t, "a", 2, 10)
    rec.run()
    rx = rec.ev("rx")
    assert [r["dist"] for r in rx] == [150.0, 300.0, 600.0]
    for r, t in zip(rx, (10.0, 20.0, 40.0), strict=True):
        assert r["t"] == pytest.approx(t + 15 * t / C + 10 * 8 / 8000, abs=1e-9)


@pytest.mark.parametrize("dmin,dmax,dist,outcome", [
    (0.5, 6.0, 5.9, "rx"), (0.5, 6.0, 6.1, "range"), (0.5, 6.0, 0.4, "range"), (0, 1e9, 5000, "rx")])
def test_range_limits_of_the_transmitter(dmin, dmax, dist, outcome):
    a = device("a", 1, min_distance=dmin, max_distance=dmax)
    b = device("b", 2)   # the receiver's own limits do not matter (as in the original)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (dist, 0, 0), b)]))
    at(rec, 0.0, "a", 2, 10)
    rec.run()
    if outcome == "rx":
        assert len(rec.ev("rx")) == 1 and not rec.ev("drop")
    else:
        (d,) = rec.ev("drop")
        assert (d["reason"], d["dev"], d["dist"], d["t"]) == ("range", "b", dist, 0.0)


def test_loss_rate_matches_per_from_the_ber_expression():
    """Broadcast to receivers at 5, 10, 20 m: one independent draw per (frame, receiver)."""
    expr = ("1e-4*m", "bit")
    a = device("a", 1, bitrate=10_000, error=expr, header_bytes=5)
    rx = [device(f"r{d}", 10 + i) for i, d in enumerate((5, 10, 20))]
    vs = [vehicle("va", (0, 0, 0), a)] + [vehicle(f"v{d}", (d, 0, 0), r) for d, r in zip((5, 10, 20), rx,
                                                                                       strict=True)]
    n = 3000
    rec = Recorded(scene(vs, [Flow(name="f", src="a", dst=255, size=20, interval=0.05)], duration=n * 0.05))
    rec.run()
    sent = len(rec.ev("tx"))
    assert sent == n
    for d in (5, 10, 20):
        r = 1e-4 * d
        per = 1 - (1 - r) ** (8 * 25)
        lost = len(rec.ev("drop", dev=f"r{d}", reason="prop"))
        assert lost + len(rec.ev("rx", dev=f"r{d}")) == n
        sigma = math.sqrt(per * (1 - per) / n)
        assert abs(lost / n - per) < 4 * sigma, (d, lost / n, per)


def _two_senders(t_a: float, t_b: float, **kw) -> Recorded:
    """a is 1500 m from r (1 s), b is 150 m from r (0.1 s); 25 B at 1000 bps = 0.2 s on air.
    a and b only transmit (they listen on channel 1) so that neither defers to the other."""
    a = device("a", 1, ch=0, rx=1, **kw)
    b = device("b", 2, ch=0, rx=1, **kw)
    r = device("r", 3)
    chans = [Channel(id=0, prop_s_per_m=1 / C), Channel(id=1, prop_s_per_m=1 / C)]
    rec = Recorded(scene([vehicle("va", (-1500, 0, 0), a), vehicle("vb", (150, 0, 0), b),
                          vehicle("vr", (0, 0, 0), r)], channels=chans))
    at(rec, t_a, "a", 3, 25)
    at(rec, t_b, "b", 3, 25)
    return rec.run()


def test_overlapping_receptions_are_both_lost():
    rec = _two_senders(1.0, 2.05)          # at r: a [2.0, 2.2], b [2.15, 2.35]
    assert [(d["src"], d["reason"]) for d in rec.ev("drop")] == [(1, "col"), (2, "col")]
    assert not rec.ev("rx")


def test_touching_receptions_do_not_collide():
    rec = _two_senders(1.0, 2.1)           # a ends at 2.2 exactly when b begins
    assert len(rec.ev("rx")) == 2 and not rec.ev("drop")


def test_a_later_transmission_that_arrives_first_still_collides():
    rec = _two_senders(1.0, 1.85)          # b sent after a but arrives at 1.95, before a (2.0)
    assert {d["reason"] for d in rec.ev("drop")} == {"col"} and len(rec.ev("drop")) == 2


def test_loss_and_collision_together_is_mult():
    rec = _two_senders(1.0, 2.05, error=("1", "packet"))
    assert {d["reason"] for d in rec.ev("drop")} == {"mult"}


def test_half_duplex_receiver_loses_what_arrives_while_it_transmits():
    a = device("a", 1)
    r = device("r", 3)
    rec = Recorded(scene([vehicle("va", (-1500, 0, 0), a), vehicle("vr", (0, 0, 0), r)]))
    at(rec, 1.0, "a", 3, 25)     # arrives at r during [2.0, 2.2]
    at(rec, 1.9, "r", 1, 25)     # r hears nothing yet and transmits during [1.9, 2.1]
    rec.run()
    assert [(d["dev"], d["reason"]) for d in rec.ev("drop")] == [("r", "col")]
    assert [r["dev"] for r in rec.ev("rx")] == ["a"]   # r's own frame reaches a intact


def test_a_half_duplex_modem_waits_for_the_end_of_what_it_hears():
    """NOMAC's implicit carrier sense: r picks its frame at 2.1 but hears a until 2.2; the frame that waited
    leaves 100 us after the reception ends, without the intrinsic delay (dccomms_ros TransmitEnqueuedPacket)."""
    a = device("a", 1)
    r = device("r", 3, intrinsic_tx_s=0.001)
    rec = Recorded(scene([vehicle("va", (-1500, 0, 0), a), vehicle("vr", (0, 0, 0), r)]))
    at(rec, 1.0, "a", 3, 25)
    at(rec, 2.1, "r", 1, 25)
    rec.run()
    assert not rec.ev("drop")
    assert [(t["dev"], t["t"]) for t in rec.ev("tx")] == [("a", 1.0), ("r", pytest.approx(2.2001))]


def test_full_duplex_receiver_keeps_receiving_while_it_transmits():
    chans = [Channel(id=0, prop_s_per_m=1 / C), Channel(id=1, prop_s_per_m=1 / C)]
    a = device("a", 1, ch=0, rx=1)
    r = device("r", 3, ch=1, rx=0)
    rec = Recorded(scene([vehicle("va", (-1500, 0, 0), a), vehicle("vr", (0, 0, 0), r)], channels=chans))
    at(rec, 1.0, "a", 3, 25)
    at(rec, 2.1, "r", 1, 25)     # full duplex: no waiting, no collision
    rec.run()
    assert [t["t"] for t in rec.ev("tx")] == [1.0, 2.1]
    assert not rec.ev("drop") and sorted(r["dev"] for r in rec.ev("rx")) == ["a", "r"]


def test_frames_for_another_address_are_not_delivered_with_addressee_delivery():
    only = ("none", {"delivery": "addressee"})
    a, b, c = device("a", 1, mac=only), device("b", 2, mac=only), device("c", 3, mac=only)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b),
                          vehicle("vc", (0, 10, 0), c)]))
    at(rec, 0.0, "a", 2, 10)
    at(rec, 1.0, "a", 255, 10)
    rec.run()
    assert [(r["dev"], r["dst"]) for r in rec.ev("rx")] == [("b", 2), ("b", 255), ("c", 255)]


def test_without_a_mac_every_modem_in_range_gets_the_frame():
    """The original's implicit broadcast: no destination filtering without a MAC, the application filters;
    the other modems' rx is traced `implicit` (and is not a delivery of the flow)."""
    a, b, c, d = device("a", 1, max_distance=2000), device("b", 2), device("c", 3), device("d", 4)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b),
                          vehicle("vc", (0, 10, 0), c), vehicle("vd", (0, 0, 3000), d)]))   # d: out of a's range
    at(rec, 0.0, "a", 2, 10)
    at(rec, 1.0, "a", 77, 10)          # an address nobody has: still on air (no "noaddr" without a MAC)
    rec.run()
    got = [(r["dev"], r["dst"], r.get("implicit", False)) for r in rec.ev("rx")]
    assert sorted(got[:2]) == [("b", 2, False), ("c", 2, True)]
    assert sorted(got[2:]) == [("b", 77, True), ("c", 77, True)]
    assert not rec.ev("drop")


def test_fifo_counts_bytes_behind_the_frame_on_air_and_drops_tail():
    a = device("a", 1, header_bytes=5, tx_fifo_bytes=50)     # room for two 25-byte frames
    b = device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)]))
    for _ in range(4):
        at(rec, 1.0, "a", 2, 20)
    rec.run()
    assert [r.get("fifo") for r in rec.ev("enq")] == [0, 25, 50, 50]
    (drop,) = rec.ev("drop")
    assert (drop["reason"], drop["seq"], drop["dev"]) == ("fifo", 3, "a")
    tx = rec.ev("tx")
    assert [t["t"] for t in tx] == pytest.approx([1.0, 1.2001, 1.4002])      # 100 us apart when queued
    assert [t["fifo"] for t in tx] == [0, 25, 0]


def test_fifo_size_zero_drops_whatever_is_offered_while_busy():
    a = device("a", 1, tx_fifo_bytes=0)
    b = device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)]))
    for t in (1.0, 1.1, 1.3):          # 25 B at 1000 bps: busy [1.0, 1.2)
        at(rec, t, "a", 2, 25)
    rec.run()
    assert [d["seq"] for d in rec.ev("drop", reason="fifo")] == [1]
    assert [r["seq"] for r in rec.ev("rx")] == [0, 2]


def test_a_frame_larger_than_the_fifo_is_refused_idle_or_busy():
    """#41: a frame that could never wait in the FIFO is refused `size` at once, whether the modem is idle
    (it used to go on air) or busy (it used to be dropped `fifo`); one that fits goes as before."""
    a = device("a", 1, tx_fifo_bytes=30)
    b = device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)]))
    at(rec, 1.0, "a", 2, 40)           # idle: 40 B > 30 B of FIFO
    at(rec, 2.0, "a", 2, 25)           # fits: on air [2.0, 2.2) at 1000 bps
    at(rec, 2.1, "a", 2, 40)           # busy: 40 B > 30 B of FIFO
    rec.run()
    assert [(d["seq"], d["reason"], d["dev"]) for d in rec.ev("drop")] == [(0, "size", "a"), (2, "size", "a")]
    assert [r["seq"] for r in rec.ev("tx")] == [1] and [r["seq"] for r in rec.ev("rx")] == [1]


def test_intrinsic_delay_keeps_the_transmitter_busy():
    a = device("a", 1, intrinsic_tx_s=0.1)
    b = device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (10, 0, 0), b)]))
    at(rec, 0.0, "a", 2, 25)
    at(rec, 0.0, "a", 2, 25)
    rec.run()
    # the second frame waited: it leaves 100 us after the first one's last bit, without the intrinsic delay
    assert [t["t"] for t in rec.ev("tx")] == pytest.approx([0.1, 0.3001])


def test_jitter_is_a_truncated_gaussian_added_to_the_intrinsic_delay():
    n = 4000
    a = device("a", 1, bitrate=80_000)
    b = device("b", 2, intrinsic_rx_s=0.05, jitter_rx_s=0.01)
    c = device("c", 3, jitter_rx_s=0.01)        # mean 0: truncation at 0 shows
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (0, 0, 0), b),
                          vehicle("vc", (0, 0, 0), c)],
                         [Flow(name="f", src="a", dst=255, size=10, interval=1.0)], duration=n))
    rec.run()
    tx_t = {r["seq"]: r["t"] for r in rec.ev("tx")}
    for dev, mean, std in (("b", 0.05, 0.01), ("c", 0.01 / math.sqrt(2 * math.pi), 0.01 * 0.5838)):
        d = [r["t"] - tx_t[r["seq"]] - 10 * 8 / 80_000 for r in rec.ev("rx", dev=dev)]
        assert len(d) == n and min(d) >= -1e-12
        mu = sum(d) / n
        sd = math.sqrt(sum((x - mu) ** 2 for x in d) / (n - 1))
        assert mu == pytest.approx(mean, abs=4 * std / math.sqrt(n))
        assert sd == pytest.approx(std, rel=0.06)
    c_delays = [r["t"] - tx_t[r["seq"]] for r in rec.ev("rx", dev="c")]
    assert 0.4 < sum(1 for x in c_delays if x <= 10 * 8 / 80_000 + 1e-12) / n < 0.6   # half clipped to 0


def test_deliveries_stay_in_order_despite_rx_jitter():
    a = device("a", 1, bitrate=80_000)
    b = device("b", 2, jitter_rx_s=0.05)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (1, 0, 0), b)],
                         [Flow(name="f", src="a", dst=2, size=10, interval=0.01)], duration=20))
    rec.run()
    seqs = [r["seq"] for r in rec.ev("rx")]
    assert seqs == sorted(seqs) and len(seqs) > 1900


def _busy_scene(seed: int):
    devs = [device(f"n{i}", i + 1, header_bytes=4, tx_fifo_bytes=60, error=("2e-5*m", "bit"),
                   intrinsic_tx_s=0.01, jitter_tx_s=0.005, jitter_rx_s=0.002, max_distance=400)
            for i in range(6)]
    vs = [vehicle(f"v{i}", (100.0 * i, 30.0 * (i % 2), 0), d) for i, d in enumerate(devs)]
    flows = [Flow(name=f"f{i}", src=f"n{i}", dst=(i + 1) % 6 + 1 if i != 5 else 255, size=20 + i,
                  interval=0.4, arrival="poisson", stop=50) for i in range(6)]
    return scene(vs, flows, duration=60, seed=seed)


def _trace_bytes(seed: int) -> bytes:
    rec = Recorded(_busy_scene(seed))
    buf = io.StringIO()
    rec.net.tracer.add(JsonlSink(buf))
    rec.run()
    return buf.getvalue().encode()


def test_same_scene_and_seed_give_a_byte_identical_trace():
    t1, t2, t3 = _trace_bytes(7), _trace_bytes(7), _trace_bytes(8)
    assert t1 == t2 and len(t1) > 10_000
    assert t1 != t3


def test_every_frame_ends_in_exactly_one_outcome_per_intended_receiver():
    rec = Recorded(_busy_scene(3)).run()
    listeners = {f"n{i}" for i in range(6)}
    outcomes: dict[tuple[int, int], list[str]] = {}
    for r in rec.records:
        if r["ev"] in ("rx", "drop") and r["kind"] == "data" and not r.get("implicit"):
            outcomes.setdefault((r["src"], r["seq"]), []).append(r["dev"])
    reasons = {r.get("reason") for r in rec.ev("drop")}
    assert {"col", "fifo", "range"} <= reasons and ("prop" in reasons or "mult" in reasons)
    enq = rec.ev("enq")
    assert len(enq) > 500
    addr_dev = {i + 1: f"n{i}" for i in range(6)}
    for e in enq:
        got = outcomes.get((e["src"], e["seq"]), [])
        src_dev = addr_dev[e["src"]]
        if any(d == src_dev for d in got):            # dropped at the transmitter (fifo)
            assert got == [src_dev]
        elif e["dst"] == 255:
            assert sorted(got) == sorted(listeners - {src_dev})
        else:
            assert got == [addr_dev[e["dst"]]]


@pytest.mark.parametrize("bitrate,sizes", [(4800, (2, 3)), (1800, (7, 30)), (9600, (1, 13))])
def test_back_to_back_frames_from_one_modem_never_collide(bitrate, sizes):
    """Consecutive frames touch at the receiver; float rounding must not turn that into a collision."""
    a = device("a", 1, bitrate=bitrate)
    b = device("b", 2)
    rec = Recorded(scene([vehicle("va", (0, 0, 0), a), vehicle("vb", (3.7, 1.1, 0), b)]))
    for i in range(40):
        at(rec, 0.0, "a", 2, sizes[i % 2])
    rec.run()
    assert not rec.ev("drop") and len(rec.ev("rx")) == 40
