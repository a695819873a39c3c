"""The saturation search (app/saturation.py) finds a maximum that can be computed by hand."""

from __future__ import annotations

import pytest
from conftest import device, scene, vehicle

from uwsimnet_zenoh.app.saturation import saturate
from uwsimnet_zenoh.errors import UserError
from uwsimnet_zenoh.scene.model import Flow


def link(distance: float = 150.0):
    """One half-duplex CS-ALOHA link, no loss: a frame is in service from its transmit() to its ACK."""
    kw = dict(bitrate=1000.0, intrinsic_tx_s=0.01, mac=("aloha", {"maxRetries": "3", "backoffMax": "0.5"}))
    return scene([vehicle("a", (0, 0, 0), device("a-m", 1, **kw)),
                  vehicle("b", (distance, 0, 0), device("b-m", 2, **kw))],
                 [Flow(name="f", src="a-m", dst=2, size=20, interval=1.0)], duration=200.0)


def test_the_maximum_of_one_acknowledged_link_is_one_frame_per_exchange():
    # intrinsic 10 ms + DATA 20 B at 1000 bit/s (160 ms) + 150 m at 1500 m/s (100 ms)
    #   + the ACK: intrinsic 10 ms + 5 B (40 ms) + 100 ms back = 420 ms per frame
    cycle = 0.01 + 20 * 8 / 1000 + 0.1 + 0.01 + 5 * 8 / 1000 + 0.1
    r = saturate(link(), "f", seeds=[1, 2], tolerance=0.02, max_delay=1.0, low=0.5, steps=10)
    assert r.rate.mean == pytest.approx(1 / cycle, rel=0.02)
    assert r.throughput.mean == pytest.approx(20 / cycle, rel=0.02)
    assert all(p.sustained == (p.rate <= 1 / cycle * 1.02) for p in r.probes if abs(p.rate * cycle - 1) > 0.03)


def test_a_longer_link_sustains_less():
    near = saturate(link(150.0), "f", seeds=[1], max_delay=1.0, low=0.5, steps=8)
    far = saturate(link(600.0), "f", seeds=[1], max_delay=2.0, low=0.5, steps=8)
    # 450 m farther: 2 x 0.3 s more per exchange
    assert 1 / far.rate.mean - 1 / near.rate.mean == pytest.approx(0.6, rel=0.05)


def test_refusals():
    with pytest.raises(UserError, match="no such flow"):
        saturate(link(), "nope")
    with pytest.raises(UserError, match="not even"):
        saturate(link(), "f", low=50.0, max_delay=0.5)


def two_senders(distance: float = 150.0):
    """Two CS-ALOHA senders a and c side by side (they hear each other at once: carrier sense works), one
    receiver b, no loss, no retry limit."""
    kw = dict(bitrate=1000.0, intrinsic_tx_s=0.01, mac=("aloha", {"maxRetries": "-1", "backoffMax": "0.5",
                                                                "maxDistance": "400"}))
    return scene([vehicle("a", (0, 0, 0), device("a-m", 1, **kw)),
                  vehicle("b", (distance, 0, 0), device("b-m", 2, **kw)),
                  vehicle("c", (0, 3, 0), device("c-m", 3, **kw))],
                 [Flow(name="f", src="a-m", dst=2, size=20, interval=1.0),
                  Flow(name="g", src="c-m", dst=2, size=20, interval=1.0)], duration=200.0)


def test_flows_scaled_together_share_the_channel():
    # alone, f sustains one frame per 420 ms exchange; scaled together with g they share the receiver, so
    # the common rate can be at most half of that, and contention (carrier sense, backoff) costs more
    cycle = 0.01 + 20 * 8 / 1000 + 0.1 + 0.01 + 5 * 8 / 1000 + 0.1
    alone = saturate(two_senders(), "f", seeds=[1], tolerance=0.02, max_delay=5.0, low=0.2, steps=6,
                     overrides={"flow.g.rate": 0.01})
    both = saturate(two_senders(), "f", seeds=[1], tolerance=0.02, max_delay=5.0, low=0.1, steps=6,
                    together=["g"])
    assert both.rate.mean <= 0.5 / cycle * 1.02
    assert both.rate.mean < alone.rate.mean
    assert all(p.throughput_ratio is not None for p in both.probes)
    with pytest.raises(UserError, match="no such flow"):
        saturate(two_senders(), "f", together=["nope"])


def test_no_retry_limit_never_drops_a_frame():
    from uwsimnet_zenoh.app.api import run
    r = run(two_senders(), seed=1, overrides={"flow.f.rate": 2.0, "flow.g.rate": 2.0})
    assert all(not m.get("drops", {}).get("retry") for m in r.flows.values())


def test_table1_summary_states_found_maxima_next_to_the_paper():
    from uwsimnet_zenoh.experiments.table1 import markdown
    c = lambda m, paper: {"mean_Bps": m, "half_Bps": 1.0, "paper_Bps": paper}   # noqa: E731
    res = {"tolerance": 0.05, "max_delay": 30.0, "seeds": [1, 2],
           "found": {"aloha": {"RF": c(75.0, 62.5), "acoustic": c(40.0, 30)},
                     "sfama": {"RF": c(30.0, 27.5), "acoustic": c(40.0, 27.5)}}}
    md = markdown(res)
    assert "| ALOHA | 75.0 ± 1.0 | 62.5 | 40.0 ± 1.0 | 30 |" in md
    assert "RF 2.50 (paper 2.27), acoustic 1.00 (paper 1.09)" in md


def test_the_original_profiles_framing_shows_in_the_delay():
    # the original profile puts 10 B more on air per DATA frame (VariableLength2B +5, Aqua-Sim's MAC
    # header +5): delay = intrinsic 10 ms + (20 + 10) B at 1000 bit/s + 150 m at 1500 m/s
    from uwsimnet_zenoh.app.api import run
    from uwsimnet_zenoh.experiments.table1 import original_overrides
    ov = {k: v for k, v in original_overrides("aloha").items() if not k.startswith("flow.")}
    plain = run(link(), seed=1, overrides={"flow.f.rate": 0.2}).flows["f"]
    framed = run(link(), seed=1, overrides={**ov, "flow.f.rate": 0.2}).flows["f"]
    assert plain["delay_mean"] == pytest.approx(0.01 + 20 * 8 / 1000 + 0.1, abs=1e-3)
    assert framed["delay_mean"] == pytest.approx(0.01 + 30 * 8 / 1000 + 0.1, abs=1e-3)
    assert framed["throughput"] == pytest.approx(plain["throughput"])     # payload B/s, not bytes on air
