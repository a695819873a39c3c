"""AcousticCommsChannel / AcousticCommsDevice: loading (legacy + native), file:line errors, engine wiring (#5)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from uwsimnet_zenoh.engine.build import DEFAULT_POWER_W, FixedBerLink
from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy.acoustic import PRESETS, AcousticLink, sound_speed_mackenzie, source_level_db
from uwsimnet_zenoh.scene import Channel, Device, SceneError, load_scene, load_scene_text
from uwsimnet_zenoh.scene.model import AcousticChannelSpec, AcousticDeviceSpec
from uwsimnet_zenoh.trace.tracer import Callback

REPO = Path(__file__).resolve().parents[1]


def _load(text: str):
    warnings: list[str] = []
    return load_scene_text(text, source="t.xml", on_warning=warnings.append), warnings


def _scene(ch: str = "", dev: str = "", top: str = "", channel_ids: str = "<txChannelId>0</txChannelId>"
           "<rxChannelId>0</rxChannelId>") -> str:
    """Channel extras at line 4, device extras at line 11, top-level extras at line 14."""
    return "\n".join([
        "<UWSimScene>",                                               # 1
        "  <AcousticCommsChannel>",                                   # 2
        "    <id>0</id>",                                             # 3
        f"    {ch}",                                                  # 4
        "  </AcousticCommsChannel>",                                  # 5
        "  <vehicle>",                                                # 6
        "    <name>a</name>",                                         # 7
        "    <AcousticCommsDevice>",                                  # 8
        "      <dccommsId>a-dev</dccommsId><mac>1</mac>",             # 9
        f"      {channel_ids}",                                       # 10
        f"      {dev}",                                               # 11
        "    </AcousticCommsDevice>",                                 # 12
        "  </vehicle>",                                               # 13
        f"  {top}",                                                   # 14
        "</UWSimScene>",                                              # 15
    ]) + "\n"


LEGACY_CHANNEL = ("<bandwidth>4096</bandwidth><temperature>12</temperature><salinity>30</salinity>"
                  "<noiseLvl>0</noiseLvl>")
LEGACY_DEVICE = ("<symbolsPerSecond>2000</symbolsPerSecond><codingEff>2</codingEff><bitErrorRate>0</bitErrorRate>"
                 "<range>3000</range><frequency>20</frequency><L>0</L><K>2.0</K><preamble>0</preamble>"
                 "<energyModel><initialEnergy>900000</initialEnergy></energyModel>"
                 "<txFifoSize>1000</txFifoSize><macProtocol><name>aloha</name></macProtocol>")


def test_legacy_elements_load_and_map() -> None:
    scene, warnings = _load(_scene(LEGACY_CHANNEL, LEGACY_DEVICE))
    (ch,) = scene.channels
    a = ch.acoustic
    assert (a.bandwidth_hz, a.temperature_c, a.salinity_ppt) == (4096.0, 12.0, 30.0)
    assert a.noise_level_db is None                  # the original's noiseLvl 0 = "not set": Wenz/Coates noise
    assert a.interference == "binary"                # the binary rule unless asked
    assert ch.prop_s_per_m == pytest.approx(1 / float(sound_speed_mackenzie(12.0, 30.0, 0.0)))
    (_, d), = scene.devices()
    assert d.bitrate == 1000.0                       # symbolsPerSecond / codingEff, as the original
    assert d.max_distance == 3000.0                  # range
    assert (d.tx_fifo_bytes, d.mac.name) == (1000, "aloha")
    s = d.acoustic
    assert (s.carrier_khz, s.spreading_k, s.bit_error_rate, s.preset) == (20.0, 2.0, 0.0, None)
    assert warnings == [
        "t.xml:11: warning: <L> in <AcousticCommsDevice> ignored (Aqua-Sim system loss factor: use"
        " <implementationLoss> in dB)",
        "t.xml:11: warning: <preamble> in <AcousticCommsDevice> ignored (Aqua-Sim preamble: use <headerBytes>"
        " for on-air overhead)",
        "t.xml:11: warning: <energyModel> in <AcousticCommsDevice> ignored (energy consumption is not simulated)",
    ]


def test_legacy_channel_id_and_noise_level() -> None:
    scene, _ = _load(_scene("<noiseLvl>70</noiseLvl>", channel_ids="<channelId>0</channelId>"))
    assert scene.channels[0].acoustic.noise_level_db == 70.0
    (_, d), = scene.devices()
    assert (d.tx_channel, d.rx_channel) == (0, 0)


NATIVE_CHANNEL = ("<depth>100</depth><ph>7.9</ph><spreading>2</spreading><absorption>francois-garrison</absorption>"
                  "<shipping>0.2</shipping><wind>7</wind><noisePsd>55</noisePsd><soundSpeed>1490</soundSpeed>"
                  "<minPropTime>2</minPropTime><interference>sinr</interference><sinrThreshold>8</sinrThreshold>")
NATIVE_DEVICE = ("<preset>whoi-micromodem</preset><sourceLevel>180</sourceLevel><bandwidth>5000</bandwidth>"
                 "<modulation>bfsk_coherent</modulation><directivityIndex>3</directivityIndex>"
                 "<implementationLoss>2</implementationLoss><margin>10</margin><headerBytes>4</headerBytes>"
                 "<intrinsicDelay>5</intrinsicDelay>")


def test_native_elements_load() -> None:
    scene, warnings = _load(_scene(NATIVE_CHANNEL, NATIVE_DEVICE))
    assert warnings == []
    (ch,) = scene.channels
    assert ch.acoustic == AcousticChannelSpec(
        line=2, depth_m=100.0, ph=7.9, spreading_k=2.0, absorption="francois-garrison", shipping=0.2,
        wind_mps=7.0, noise_psd_db=55.0, sound_speed_mps=1490.0, interference="sinr", sinr_threshold_db=8.0)
    assert ch.prop_s_per_m == pytest.approx(1 / 1490) and ch.min_prop_s == pytest.approx(0.002)
    (_, d), = scene.devices()
    assert d.bitrate == PRESETS["whoi-micromodem"].bitrate_bps      # from the preset
    assert d.acoustic == AcousticDeviceSpec(
        line=8, preset="whoi-micromodem", source_level_db=180.0, bandwidth_hz=5000.0, modulation="bfsk_coherent",
        directivity_index_db=3.0, implementation_loss_db=2.0, margin_db=10.0)
    assert (d.header_bytes, d.intrinsic_tx_s) == (4, 0.005)


def test_capture_first() -> None:
    scene, _ = _load(_scene("<interference>sinr</interference><capture>first</capture>"
                            "<acquireThreshold>12</acquireThreshold>"))
    a = scene.channels[0].acoustic
    assert (a.capture, a.acquire_threshold_db, a.sinr_threshold_db) == ("first", 12.0, None)
    assert Network(scene).channels[0].lock_first_db == 12.0
    scene, _ = _load(_scene("<interference>sinr</interference>"))
    assert scene.channels[0].acoustic.capture == "any" and Network(scene).channels[0].lock_first_db is None


def test_absorption_number_and_power() -> None:
    scene, _ = _load(_scene("<absorption>3.5</absorption>", "<power>10</power><bitrate>500</bitrate>"))
    assert scene.channels[0].acoustic.absorption == 3.5
    (_, d), = scene.devices()
    assert (d.acoustic.power_w, d.bitrate) == (10.0, 500.0)


@pytest.mark.parametrize(("ch", "dev", "top", "expected"), [
    ("", "<preset>evologics-x</preset>", "",
     "11: preset: unknown preset 'evologics-x' (known: evologics-s2cr-18-34, evologics-s2cr-7-17, seatrac-x150,"
     " whoi-micromodem, whoi-micromodem-psk5400)"),
    ("", "<sourceLevel>180</sourceLevel><power>2</power>", "",
     "11: sourceLevel: give either <sourceLevel> (dB re 1 uPa @ 1 m) or <power> (W), not both"),
    ("", "<bitrate>100</bitrate><symbolsPerSecond>100</symbolsPerSecond>", "",
     "11: bitrate: give either <bitrate> or <symbolsPerSecond>/<codingEff>, not both"),
    ("", "<codingEff>2</codingEff>", "",
     "11: codingEff: needs <symbolsPerSecond> (bit rate = symbolsPerSecond / codingEff)"),
    ("", "<symbolsPerSecond>100</symbolsPerSecond><codingEff>0</codingEff>", "",
     "11: codingEff: must be greater than 0, got 0"),
    ("", "<symbolsPerSecond>-100</symbolsPerSecond>", "", "11: symbolsPerSecond: must be greater than 0, got -100"),
    ("", "<range>100</range><maxDistance>200</maxDistance>", "",
     "11: range: give either <range> or <maxDistance>, not both"),
    ("", "<minDistance>50</minDistance><range>10</range>", "", "11: minDistance 50 is larger than range 10"),
    ("", "<modulation>qam</modulation>", "",
     "11: modulation: expected bpsk, bfsk_coherent, bfsk_noncoherent, dpsk or bpsk_rayleigh, got 'qam'"),
    ("", "<bitErrorRate>1.5</bitErrorRate>", "", "11: bitErrorRate: must be at most 1, got 1.5"),
    ("", "<power>0</power>", "", "11: power: must be greater than 0, got 0"),
    ("", "<frequency>fast</frequency>", "", "11: frequency: expected a number, got 'fast'"),
    ("", "<rateErrorModel><errorRateExpr>0</errorRateExpr></rateErrorModel>", "",
     "11: unknown element <rateErrorModel> in <AcousticCommsDevice>"),
    ("<sinrThreshold>8</sinrThreshold>", "", "", "4: sinrThreshold: needs <interference>sinr</interference>"),
    ("<capture>first</capture>", "", "", "4: capture: needs <interference>sinr</interference>"),
    ("<interference>sinr</interference><capture>all</capture>", "", "", "4: capture: expected any or first, got 'all'"),
    ("<interference>sinr</interference><acquireThreshold>10</acquireThreshold>", "", "",
     "4: acquireThreshold: needs <capture>first</capture>"),
    ("<interference>capture</interference>", "", "", "4: interference: expected binary or sinr, got 'capture'"),
    ("<absorption>fg</absorption>", "", "",
     "4: absorption: expected thorp, francois-garrison or a number (dB/km), got 'fg'"),
    ("<absorption>-1</absorption>", "", "",
     "4: absorption: must be thorp, francois-garrison or a number >= 0 (dB/km), got -1"),
    ("<temperature>80</temperature>", "", "", "4: temperature: must be at most 50, got 80"),
    ("<shipping>2</shipping>", "", "", "4: shipping: must be at most 1, got 2"),
    ("<soundSpeed>0</soundSpeed>", "", "", "4: soundSpeed: must be greater than 0, got 0"),
    ("<propTimeIncPerMeter>0.6667</propTimeIncPerMeter>", "", "",
     "4: unknown element <propTimeIncPerMeter> in <AcousticCommsChannel>"),
    ("<windSpeed>3</windSpeed>", "", "", "4: unknown element <windSpeed> in <AcousticCommsChannel>"),
    ("", "", "<CustomCommsChannel><id>0</id></CustomCommsChannel>", "14: duplicate channel id 0 (first at line 3)"),
])
def test_bad_acoustic_scene(ch: str, dev: str, top: str, expected: str) -> None:
    with pytest.raises(SceneError) as info:
        _load(_scene(ch, dev, top))
    assert str(info.value) == f"t.xml:{expected}"


def test_channel_id_with_tx_rx_is_an_error() -> None:
    with pytest.raises(SceneError, match=r"t.xml:10: txChannelId: give either <channelId> or"):
        _load(_scene(channel_ids="<channelId>0</channelId><txChannelId>0</txChannelId>"))


def test_acoustic_device_needs_acoustic_channels() -> None:
    top = "<CustomCommsChannel><id>1</id></CustomCommsChannel>"
    with pytest.raises(SceneError) as info:
        _load(_scene(top=top, channel_ids="<txChannelId>0</txChannelId><rxChannelId>1</rxChannelId>"))
    assert str(info.value) == ("t.xml:10: rxChannelId: channel 1 is a CustomCommsChannel; an AcousticCommsDevice"
                               " needs an AcousticCommsChannel")
    with pytest.raises(SceneError, match=r"t.xml:10: txChannelId: no AcousticCommsChannel with id 5"):
        _load(_scene(channel_ids="<txChannelId>5</txChannelId><rxChannelId>0</rxChannelId>"))


def test_custom_device_may_not_transmit_on_a_sinr_channel() -> None:
    custom = ("<vehicle><name>b</name><CustomCommsDevice><dccommsId>b-dev</dccommsId><mac>2</mac>"
              "<txChannelId>0</txChannelId><rxChannelId>0</rxChannelId></CustomCommsDevice></vehicle>")
    scene, _ = _load(_scene(top=custom))                  # binary acoustic channel: fine (sound speed delay)
    assert scene.devices()[1][1].acoustic is None
    with pytest.raises(SceneError) as info:
        _load(_scene("<interference>sinr</interference>", top=custom))
    assert str(info.value).startswith("t.xml:14: txChannelId: channel 0 decides collisions by SINR")


def test_disabled_acoustic_device_is_skipped() -> None:
    scene, warnings = _load(_scene(dev="<disable>1</disable>"))
    assert scene.devices() == [] and warnings == ["t.xml:8: warning: <AcousticCommsDevice> 'a-dev' is disabled"
                                                  " (<disable>), skipped"]


# ------------------------------------------------------------------------------------- engine wiring

def test_network_gives_acoustic_modems_their_link_and_delay() -> None:
    scene, _ = _load(_scene(NATIVE_CHANNEL, NATIVE_DEVICE))
    net = Network(scene)
    m = net.modems["a-dev"]
    assert isinstance(m.error, AcousticLink)
    link = m.error
    assert link.sl_db == 180.0 and link.modem.modulation == "bfsk_coherent"
    assert link.modem.bandwidth_hz == 5000.0 and link.modem.bitrate_bps == 80.0 and link.modem.margin_db == 10.0
    assert link.channel.spreading_k == 2.0 and link.channel.absorption == "francois-garrison"
    assert link.nl_db == pytest.approx(55 + 10 * math.log10(5000) + 10)
    ch = net.channels[0]
    assert ch.sinr and ch.sinr_threshold_db == 8.0
    assert ch.max_prop_delay(1490.0) == pytest.approx(0.002 + 1.0)
    assert m.bitrate == 80.0


def test_legacy_device_defaults_and_fixed_ber() -> None:
    scene, _ = _load(_scene(LEGACY_CHANNEL, LEGACY_DEVICE.replace("<bitErrorRate>0</bitErrorRate>",
                                                                  "<bitErrorRate>1e-4</bitErrorRate>")))
    m = Network(scene).modems["a-dev"]
    assert isinstance(m.error, FixedBerLink)
    assert float(m.error.per(1234.0, 10)) == pytest.approx(1 - (1 - 1e-4) ** 80)
    link = m.error.link
    assert link.sl_db == pytest.approx(float(source_level_db(DEFAULT_POWER_W)))   # the original's PT 0.2818 W
    assert (link.modem.carrier_khz, link.modem.bandwidth_hz, link.modem.bitrate_bps) == (20.0, 4096.0, 1000.0)
    assert link.channel.spreading_k == 2.0                                        # the device's K


def test_end_to_end_delay_uses_the_sound_speed() -> None:
    text = _scene("<soundSpeed>1480</soundSpeed>", "<preset>evologics-s2cr-18-34</preset>",
                  "<vehicle><name>b</name><position>740 0 0</position><AcousticCommsDevice><dccommsId>b-dev"
                  "</dccommsId><mac>2</mac><channelId>0</channelId><preset>evologics-s2cr-18-34</preset>"
                  "</AcousticCommsDevice></vehicle>")
    scene, _ = _load(text)
    net = Network(scene)
    got = []
    net.tracer.listen(Callback(lambda t, ev, ch, dev, f, *_: got.append(t) if ev == "rx" and dev == "b-dev" else None))
    net.sched.at(1.0, lambda: net.modems["a-dev"].send(2, 139))
    net.run(10.0)
    assert got == [pytest.approx(1.0 + 740 / 1480 + 139 * 8 / 13900, abs=1e-9)]


def test_device_model_defaults_in_code() -> None:
    d = Device(dccomms_id="x", address=1, tx_channel=0, rx_channel=0,
               acoustic=AcousticDeviceSpec(preset="seatrac-x150"))
    assert d.bitrate == 100.0
    d = Device(dccomms_id="x", address=1, tx_channel=0, rx_channel=0, bitrate=80.0,
               acoustic={"preset": "seatrac-x150"})
    assert d.bitrate == 80.0                                    # explicit wins
    assert Device(dccomms_id="x", address=1, tx_channel=0, rx_channel=0, acoustic={}).bitrate == 1000.0
    c = Channel(id=0, acoustic=AcousticChannelSpec(sound_speed_mps=1500.0))
    assert c.prop_s_per_m == pytest.approx(1 / 1500)
    assert Channel(id=0, prop_s_per_m=0.001, acoustic=AcousticChannelSpec()).prop_s_per_m == 0.001
    with pytest.raises(ValueError, match="sinrThreshold needs interference sinr"):
        AcousticChannelSpec(sinr_threshold_db=3.0)
    with pytest.raises(ValueError, match="either a source level or a power"):
        AcousticDeviceSpec(source_level_db=180.0, power_w=1.0)


def test_example_scene_loads_without_warnings_and_is_in_the_docs() -> None:
    warnings: list[str] = []
    scene = load_scene(REPO / "scenes/examples/acoustic-capture.xml", on_warning=warnings.append)
    assert warnings == []
    assert scene.channels[0].acoustic.interference == "sinr"
    assert all(d.acoustic.preset == "evologics-s2cr-18-34" and d.bitrate == 13_900 for _, d in scene.devices())
    doc = (REPO / "docs/acoustic.md").read_text()
    text = (REPO / "scenes/examples/acoustic-capture.xml").read_text()
    assert text[text.index("<UWSimScene>"):] in doc
