"""Issue #41: the online metrics of a run hold a bounded state however long it runs.  Frames settle once
quiet for `settle_after` (their state let go: the held count stays bounded), the delays are binned beyond
fold.EXACT of them (the median and p95 within 1/(2 fold.SUB) of numpy's on the exact delays), and the
result is the same as the report of the whole trace, which holds every frame to the end."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from uwsimnet_zenoh.analysis import Accumulator, analyse, report_json
from uwsimnet_zenoh.analysis.fold import EXACT, SUB, SWEEP
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.scene.load import load_scene_text

REL = 1 / (2 * SUB)     # the documented precision of a binned quantile


def line_scene(n: int, duration: float) -> str:
    """n modems 100 m apart, each sending one 16 B frame a second to its neighbour (bench/bench_soak.py's)."""
    vs, flows = [], []
    for i in range(n):
        vs.append(f"""<vehicle><name>v{i}</name><position>{100 * i} 0 10</position><CustomCommsDevice>
<dccommsId>m{i}</dccommsId><mac>{i + 1}</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>
<bitrate>100000</bitrate><txFifoSize>100000</txFifoSize><maxDistance>150</maxDistance></CustomCommsDevice>
</vehicle>""")
        flows.append(f"<flow><name>f{i}</name><src>m{i}</src><dst>{i + 2 if i + 1 < n else i}</dst><size>16</size>"
                     f"<interval>1</interval><arrival>poisson</arrival><start>{i / n:.4f}</start></flow>")
    return f"""<UWSimScene><simulation><seed>4</seed><duration>{duration}</duration></simulation>
<CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
{''.join(vs)}{''.join(flows)}</UWSimScene>"""


def test_a_long_run_holds_a_bounded_state_and_reports_what_the_whole_trace_does():
    n, duration, after = 16, 1500.0, 60.0
    net = Network(load_scene_text(line_scene(n, duration)))
    recs: list[dict] = []
    net.tracer.add(recs.append)
    acc = Accumulator(net.meta(), settle_after=after)
    held: list[int] = []
    net.tracer.consume(acc.on_batch)
    net.tracer.consume(lambda b: held.append(len(acc._fold.frames)))
    net.run()
    net.tracer.flush()
    a = acc.result()
    whole = analyse([net.meta(), *recs])
    assert report_json(a.flows) == report_json(whole.flows)
    assert list(a.conservation) == list(whole.conservation) == []
    assert a.conservation.frames == whole.conservation.frames > 5 * SWEEP
    # held: at most twice the frames of the last `after` s (plus the ones on air), or the first sweep's count
    assert max(held) <= max(SWEEP, 2 * n * (after + 5) * 1.3), max(held)
    delivered = sum(f.delivered for f in a.flows.values())
    assert delivered > EXACT                        # the delays were binned: both sides the same
    assert acc._fold.binned


def test_binned_quantiles_are_within_their_stated_precision_of_numpys():
    rng = random.Random(7)
    acc = Accumulator({}, settle_after=30.0)
    delays: list[float] = []
    t = 0.0
    for seq in range(3 * EXACT):
        t += rng.expovariate(50.0)
        d = rng.lognormvariate(0.0, 1.5)            # 0.01 s to 100 s: many octaves
        delays.append(round(t + d, 9) - round(t, 9))
        acc.event(round(t, 9), "enq", 0, "a", 1, 2, seq, 20, "f", "data", None, False)
        acc.event(round(t, 9), "tx", 0, "a", 1, 2, seq, 20, "f", "data", None, False)
        acc.event(round(t + d, 9), "rx", 0, "b", 1, 2, seq, 20, "f", "data", None, True)
    f = acc.result().flows["f"]
    assert f.delay_median == pytest.approx(float(np.median(delays)), rel=REL)
    assert f.delay_p95 == pytest.approx(float(np.percentile(delays, 95)), rel=REL)
    assert f.delay_median != float(np.median(delays))     # binned, not exact
    assert math.isclose(f.delay_mean, math.fsum(delays) / len(delays), rel_tol=1e-14)


def test_few_delays_stay_exact():
    acc = Accumulator({})
    delays = [0.1 * k + 0.0123 for k in range(1, 101)]
    for seq, d in enumerate(delays):
        acc.event(float(seq), "enq", 0, "a", 1, 2, seq, 20, "f", "data", None, False)
        acc.event(float(seq), "tx", 0, "a", 1, 2, seq, 20, "f", "data", None, False)
        acc.event(seq + d, "rx", 0, "b", 1, 2, seq, 20, "f", "data", None, True)
    got = [(seq + d) - float(seq) for seq, d in enumerate(delays)]
    f = acc.result().flows["f"]
    assert (f.delay_median, f.delay_p95) == (float(np.median(got)), float(np.percentile(got, 95)))
    assert f.delay_mean == float(np.mean(got))


def _feed(acc: Accumulator, n: int) -> Accumulator:
    """n frames, one a second, each delivered 0.5 s later but seq 5 (no outcome: a violation)."""
    for seq in range(n):
        acc.event(float(seq), "enq", 0, "a", 1, 2, seq, 20, "f", "data", None, False)
        acc.event(float(seq), "tx", 0, "a", 1, 2, seq, 20, "f", "data", None, False)
        if seq != 5:
            acc.event(seq + 0.5, "rx", 0, "b", 1, 2, seq, 20, "f", "data", None, True)
    return acc


def test_frames_settle_past_a_violation_and_an_event_of_a_settled_frame_is_one():
    n = 3 * SWEEP
    acc = _feed(Accumulator({}, settle_after=10.0), n)     # each sweep settles all but the last 10 s
    fold = acc._fold
    assert len(fold.frames) < SWEEP and len(fold.senders["a"].seqs) < SWEEP   # seq 5 holds no one else
    assert report_json(acc.result().flows) == report_json(_feed(Accumulator({}), n).result().flows)
    acc = _feed(Accumulator({}, settle_after=10.0), n)
    acc.event(float(n), "rx", 0, "b", 1, 2, 3, 20, "f", "data", None, True)   # seq 3 again, long after
    c = acc.result().conservation
    assert c.total == 2 and c.frames == n, list(c)
    assert c[0] == f"a seq 5 (flow f): transmitted at 5 s, no outcome by the end ({n} s)", list(c)
    assert c[1].startswith(f"a seq 3: rx at {float(n)} s, after its frame was settled"), list(c)


def test_a_frame_to_an_address_nobody_has_ends_noaddr_not_in_flight():
    """#41: on a channel without MAC a unicast frame goes on air whatever its address (the others get it
    implicitly); to an address no modem has, nobody could ever receive it: its outcome is `noaddr` at once,
    so it is neither in flight at the end nor a violation, whenever the run stops."""
    sc = load_scene_text(line_scene(2, 200.0).replace("<dst>2</dst>", "<dst>99</dst>"))
    for until in (200.0, 95.0):                     # the whole run, and one cut 5 s after a transmission
        net = Network(sc)
        recs: list[dict] = []
        net.tracer.add(recs.append)
        net.run(until)
        a = analyse([net.meta(), *recs], end=until)
        f0 = a.flows["f0"]
        assert list(a.conservation) == [] and a.conservation.in_flight == []
        assert f0.sent == sum(r["ev"] == "tx" and r["dev"] == "m0" for r in recs) > 0
        assert f0.drops == {"noaddr": f0.sent} and f0.delivered == 0 and f0.delivery_ratio == 0.0
        assert any(r["ev"] == "rx" and r.get("implicit") for r in recs)     # heard by m1, not delivered
        assert a.flows["f1"].delivered == a.flows["f1"].sent              # m1 -> m0 unaffected
