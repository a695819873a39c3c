"""Propagation time over Zenoh: the broker's modem `info` carries the tx channel's delay law (`prop`), and
`ZenohBackend` (what `uwsimnet emulate` sits on) uses it, so the delivery reports an emulator gives a device
(DELIVEREDIM after one propagation time) follow the channel the PHY simulates, not a fixed 1500 m/s.

Checked for a custom channel (minPropTime + propTimeIncPerMeter * d) and an acoustic one (d / Mackenzie
sound speed), against the formulas and against phy.channel.Channel of the same scene, through a real
broker process."""

from __future__ import annotations

import math
import queue
from pathlib import Path

import pytest
from test_broker_e2e import Broker
from uwsimnet_gli.wire import Keys

from uwsimnet_zenoh.bus.session import make_config, open_session
from uwsimnet_zenoh.drivers.backend import BackendStatus
from uwsimnet_zenoh.drivers.zenoh_backend import FALLBACK_SOUND_SPEED, ZenohBackend, prop_law, query_info
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy.acoustic import sound_speed_mackenzie
from uwsimnet_zenoh.scene.load import load_scene_text

WORLD = "propinfo"
T, S, DEPTH = 12.0, 34.0, 40.0                 # the acoustic channel's water
MIN_MS, PER_M_MS = 3.0, 0.5                    # the custom channel: 3 ms + 0.5 ms/m (not 1/1500 s/m)
B_POS = (300.0, 400.0, 0.0)                    # 500 m exactly from the origin (the trace keeps mm)
DIST = math.dist((0.0, 0.0, 0.0), B_POS)


def custom_dev(dev: str, mac: int) -> str:
    return (f"<CustomCommsDevice><dccommsId>{dev}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>"
            f"<rxChannelId>0</rxChannelId><bitrate>10000</bitrate><maxDistance>2000</maxDistance>"
            f"<rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>"
            f"</CustomCommsDevice>")


def acoustic_dev(dev: str, mac: int) -> str:
    return (f"<AcousticCommsDevice><dccommsId>{dev}</dccommsId><mac>{mac}</mac><txChannelId>1</txChannelId>"
            f"<rxChannelId>1</rxChannelId><preset>evologics-s2cr-18-34</preset></AcousticCommsDevice>")


SCENE = f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>{WORLD}</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>{PER_M_MS}</propTimeIncPerMeter>
    <minPropTime>{MIN_MS}</minPropTime></CustomCommsChannel>
  <AcousticCommsChannel><id>1</id><temperature>{T}</temperature><salinity>{S}</salinity><depth>{DEPTH}</depth>
  </AcousticCommsChannel>
  <CustomCommsChannel><id>2</id><propTimeIncPerMeter>2</propTimeIncPerMeter>
    <minPropTime>7</minPropTime></CustomCommsChannel>
  <vehicle><name>a</name><position>0 0 0</position>{custom_dev("c-a", 1)}{acoustic_dev("k-a", 1)}
    {custom_dev("m-a", 3).replace("<rxChannelId>0</rxChannelId>", "<rxChannelId>2</rxChannelId>")}</vehicle>
  <vehicle><name>b</name><position>{B_POS[0]} {B_POS[1]} {B_POS[2]}</position>{custom_dev("c-b", 2)}
    {acoustic_dev("k-b", 2)}
    {custom_dev("m-b", 4).replace("<txChannelId>0</txChannelId>", "<txChannelId>2</txChannelId>")}</vehicle>
</UWSimScene>"""

# (tx modem, its channel id, the delay law by formula)
CASES = [("c-a", 0, lambda d: MIN_MS / 1e3 + PER_M_MS / 1e3 * d),
         ("k-a", 1, lambda d: d / float(sound_speed_mackenzie(T, S, DEPTH)))]


@pytest.fixture(scope="module")
def phy() -> Network:
    """The PHY of the same scene, in process: its Channel objects are what the broker simulates with."""
    return Network(load_scene_text(SCENE), flows=False)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    d: Path = tmp_path_factory.mktemp("prop")
    (d / "s.xml").write_text(SCENE)
    b = Broker(d / "s.xml", d / "trace.jsonl")
    try:
        with open_session(make_config("client", connect=[b.endpoint], connect_timeout_ms=3000)) as s:
            yield s
    finally:
        assert b.stop() == 0, b.output()


@pytest.mark.parametrize("dev,cid,formula", CASES, ids=["custom", "acoustic"])
def test_info_reply_carries_the_tx_channel_delay_law(session, phy, dev, cid, formula):
    info = query_info(session, Keys(WORLD), dev)
    assert info is not None and info["tx_channel"] == cid
    ch = phy.channels[cid]
    assert info["prop"] == {"min": ch.min_prop_s, "per_m": ch.prop_s_per_m}
    assert info["prop"]["min"] + info["prop"]["per_m"] * DIST == pytest.approx(formula(DIST), abs=1e-12)


@pytest.mark.parametrize("dev,cid,formula", CASES, ids=["custom", "acoustic"])
def test_zenoh_backend_propagation_is_the_channels(session, phy, dev, cid, formula):
    ch = phy.channels[cid]
    be = ZenohBackend(session, WORLD, dev)
    try:
        assert be.prop_known
        for d in (0.0, 1.0, 123.456, DIST, 4321.0):
            assert abs(be.prop_time(d) - ch.max_prop_delay(d)) < 1e-9
            assert abs(be.prop_time(d) - formula(d)) < 1e-9

        # what an emulator is told: the delivery outcome of a unicast frame, with its propagation time
        got: queue.Queue[BackendStatus] = queue.Queue()
        be.on_status.append(lambda st: got.put(st) if st.event in ("delivered", "lost") else None)
        be.send(2, b"how far?", tag="t1")
        st = got.get(timeout=10)
        assert (st.tag, st.event) == ("t1", "delivered"), st
        assert st.prop_time is not None and abs(st.prop_time - ch.max_prop_delay(DIST)) < 1e-9
    finally:
        be.close()


def test_received_frames_use_the_rx_channels_law(session, phy):
    """m-a sends on channel 0 and listens on channel 2 (7 ms + 2 ms/m): a frame it receives crossed
    channel 2, and that is the propagation time its backend reports, not the tx channel's."""
    ch2 = phy.channels[2]
    info = query_info(session, Keys(WORLD), "m-a")
    assert info["rx_prop"] == {"min": ch2.min_prop_s, "per_m": ch2.prop_s_per_m}
    assert info["prop"] == {"min": phy.channels[0].min_prop_s, "per_m": phy.channels[0].prop_s_per_m}
    rx, tx = ZenohBackend(session, WORLD, "m-a"), ZenohBackend(session, WORLD, "m-b")
    try:
        got: queue.Queue = queue.Queue()
        rx.on_frame.append(got.put)
        tx.send(3, b"over channel 2")
        f = got.get(timeout=10)
        assert f.distance == pytest.approx(DIST, abs=1e-6)
        assert abs(f.prop_time - (7e-3 + 2e-3 * DIST)) < 1e-9
        assert abs(f.prop_time - ch2.max_prop_delay(DIST)) < 1e-9
    finally:
        rx.close()
        tx.close()


def test_a_broker_without_prop_falls_back_to_1500_m_per_s():
    assert prop_law({"address": 1}) == (0.0, 1.0 / FALLBACK_SOUND_SPEED, False)
    for bad in ({"min": -1.0, "per_m": 1e-3}, {"min": 0.0, "per_m": float("nan")}, {"per_m": 1e-3}, [1, 2]):
        assert prop_law({"prop": bad})[2] is False, bad
    assert prop_law({"prop": {"min": 0.002, "per_m": 1e-3}}) == (0.002, 1e-3, True)
