"""Scene loading: the legacy UWSim-NET vocabulary, the native extensions, and `file:line: message` errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from uwsimnet_zenoh.scene import (
    Channel,
    Device,
    ErrorModel,
    Flow,
    MacSpec,
    Scene,
    SceneError,
    Simulation,
    Tracing,
    Vehicle,
    Waypoint,
    load_scene,
    load_scene_text,
)

REPO = Path(__file__).resolve().parents[1]


def _strip_lines(obj):
    """model_dump() without the bookkeeping `line` fields, for value comparisons."""
    if isinstance(obj, dict):
        return {k: _strip_lines(v) for k, v in obj.items() if k != "line"}
    if isinstance(obj, list | tuple):
        return [_strip_lines(v) for v in obj]
    return obj


def _load(text: str, source: str = "t.xml") -> tuple[Scene, list[str]]:
    warnings: list[str] = []
    return load_scene_text(text, source=source, on_warning=warnings.append), warnings


# ------------------------------------------------------------------------------------- legacy scene

LEGACY = """\
<?xml version="1.0"?>
<!DOCTYPE UWSimScene SYSTEM "UWSimScene.dtd">
<UWSimScene>
  <oceanState>
    <windx> 0.04 </windx>
    <fog><density> 0.1 </density><color><r>0</r><g>0</g><b>0.1</b></color></fog>
  </oceanState>
  <camera>
    <fov> 60 </fov>
    <position><x>-3</x><y>0</y><z>-1</z></position>
  </camera>
  <netTracingScript>
    <className>ErrorsTracing</className>
    <libPath>libnetsim_tracing_examples.so</libPath>
    <logToFile></logToFile>
  </netTracingScript>
  <CustomCommsChannel>
    <id>0</id>
    <!-- acoustic speed in water ms/m-->
    <propTimeIncPerMeter>0.6667</propTimeIncPerMeter>
    <minPropTime>0</minPropTime>
  </CustomCommsChannel>
  <vehicle>
    <name>bluerov_0</name>
    <file>data/scenes/bluerov2.urdf</file>
    <jointValues><joint>0</joint></jointValues>
    <position>
      <x> 1 </x>
      <y> 0 </y>
      <z> 4 </z>
    </position>
    <CustomCommsDevice>
      <dccommsId>bluerov0-dev</dccommsId>
      <txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId>
      <relativeTo>base_link</relativeTo>
      <mac>1</mac>
      <bitrate>600</bitrate>
      <txFifoSize>200</txFifoSize>
      <tfId>bluerov0-dev</tfId>
      <!-- instrinsic delay in ms -->
      <intrinsicDelay>1</intrinsicDelay>
      <!-- range limits in meters -->
      <maxDistance>100</maxDistance>
      <minDistance>0</minDistance>
      <rateErrorModel>
        <errorUnit>bit</errorUnit>
        <errorRateExpr>6e-13*m^13.7</errorRateExpr>
      </rateErrorModel>
      <txPacketBuilder>
        <className>VariableLength2BPacketBuilder</className>
      </txPacketBuilder>
    </CustomCommsDevice>
  </vehicle>
  <vehicle>
    <name>bluerov_1</name>
    <file>data/scenes/bluerov2.urdf</file>
    <position><x>0</x><y>0</y><z>4</z></position>
    <CustomCommsDevice>
      <dccommsId>bluerov1-dev</dccommsId>
      <txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId>
      <mac>2</mac>
      <bitrate>600</bitrate>
      <txFifoSize>200</txFifoSize>
      <intrinsicDelay>1</intrinsicDelay>
      <macProtocol><name>sfama</name><maxBackoffSlots>10</maxBackoffSlots></macProtocol>
    </CustomCommsDevice>
  </vehicle>
  <rosInterfaces>
    <CustomCommsDeviceROS><name>bluerov0-dev</name><topic>bluerov0/commsdev</topic></CustomCommsDeviceROS>
  </rosInterfaces>
</UWSimScene>
"""


def test_legacy_scene_loads_with_warnings_and_converted_units(tmp_path: Path) -> None:
    path = tmp_path / "prop-errors.xml"
    path.write_text(LEGACY)
    warnings: list[str] = []
    scene = load_scene(path, on_warning=warnings.append)

    src = str(path)
    assert warnings == [
        f"{src}:4: warning: <oceanState> ignored (UWSim 3D scene element)",
        f"{src}:8: warning: <camera> ignored (UWSim 3D scene element)",
        f"{src}:13: warning: netTracingScript: C++ tracing class 'ErrorsTracing' is not supported, ignored"
        " (name a Python class as module:Class)",
        f"{src}:25: warning: <file> in <vehicle> ignored (UWSim 3D scene element)",
        f"{src}:26: warning: <jointValues> in <vehicle> ignored (UWSim 3D scene element)",
        f"{src}:36: warning: <relativeTo> in <CustomCommsDevice> ignored"
        " (ROS TF frame: the modem sits at the vehicle position)",
        f"{src}:40: warning: <tfId> in <CustomCommsDevice> ignored"
        " (ROS TF frame: the modem sits at the vehicle position)",
        f"{src}:57: warning: <file> in <vehicle> ignored (UWSim 3D scene element)",
        f"{src}:59: warning: no rateErrorModel: assuming no propagation loss (the original assumed 0.01*m)",
        f"{src}:70: warning: <rosInterfaces> ignored (ROS interfaces: applications reach modems through Zenoh"
        " keys)",
    ]

    assert scene.name == "prop-errors"
    assert scene.world == "prop-errors"
    assert scene.source == src
    assert scene.tracing == Tracing(line=12)          # the C++ class is dropped
    assert scene.simulation == Simulation()
    (ch,) = scene.channels
    assert ch.id == 0 and ch.line == 17
    assert ch.prop_s_per_m == pytest.approx(6.667e-4, rel=1e-12)
    assert ch.min_prop_s == 0.0

    v0, v1 = scene.vehicles
    assert (v0.name, v0.position, v0.line) == ("bluerov_0", (1.0, 0.0, 4.0), 23)
    assert v1.position == (0.0, 0.0, 4.0)
    (d0,) = v0.devices
    assert d0.line == 32
    assert (d0.dccomms_id, d0.address, d0.tx_channel, d0.rx_channel) == ("bluerov0-dev", 1, 0, 0)
    assert d0.half_duplex
    assert d0.bitrate == 600.0
    assert d0.tx_fifo_bytes == 200
    assert d0.intrinsic_tx_s == pytest.approx(0.001, rel=1e-12)
    assert d0.intrinsic_rx_s == 0.0
    assert (d0.max_distance, d0.min_distance) == (100.0, 0.0)
    assert d0.error == ErrorModel(line=46, unit="bit", expr="6e-13*m^13.7")
    assert d0.mac == MacSpec()
    assert (d0.tx_framing, d0.rx_framing) == ("VariableLength2BPacketBuilder", None)
    assert d0.max_frame_bytes == 2053                 # the framing's largest frame
    (d1,) = v1.devices
    assert d1.tx_framing is None and d1.max_frame_bytes == 2048
    assert d1.error == ErrorModel()                   # no loss, not the original's 0.01*m
    assert d1.mac == MacSpec(line=67, name="sfama", params={"maxBackoffSlots": "10"})
    assert d1.max_distance == 99_999_999.0
    assert scene.flows == ()


# ------------------------------------------------------------------------------------- native scene

NATIVE = """\
<UWSimScene>
  <simulation>
    <duration>120</duration>
    <seed>42</seed>
    <clock>realtime</clock>
    <world>lab</world>
  </simulation>
  <netTracingScript>
    <className>mypkg.tracing:Counter</className>
    <logToFile>run.log</logToFile>
  </netTracingScript>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  <CustomCommsChannel><id>1</id><propTimeIncPerMeter>3.333333333e-06</propTimeIncPerMeter>
    <minPropTime>2</minPropTime></CustomCommsChannel>
  <vehicle>
    <name>auv</name>
    <trajectory>
      <waypoint t="0" x="0" y="0" z="5"/>
      <waypoint><t>10</t><x>50</x><y>0</y><z>5</z></waypoint>
      <waypoint t="20.5" x="50" y="25" z="7.5"/>
    </trajectory>
    <poseRate>20</poseRate>
    <CustomCommsDevice>
      <dccommsId>auv-ac</dccommsId>
      <mac>1</mac>
      <txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId>
      <bitrate>1000</bitrate>
      <txFifoSize>0</txFifoSize>
      <intrinsicDelay><tx>2</tx><rx>3.5</rx></intrinsicDelay>
      <jitter><tx>0.5</tx><rx>1</rx></jitter>
      <maxDistance>500</maxDistance>
      <minDistance>1</minDistance>
      <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0.001*m</errorRateExpr></rateErrorModel>
      <macProtocol><name>aloha</name><maxBackoff>2.5</maxBackoff></macProtocol>
      <headerBytes>12</headerBytes>
      <maxFrameBytes>256</maxFrameBytes>
    </CustomCommsDevice>
    <CustomCommsDevice>
      <dccommsId>auv-rf</dccommsId>
      <mac>1</mac>
      <txChannelId>1</txChannelId>
      <rxChannelId>1</rxChannelId>
      <rateErrorModel><errorRateExpr>0</errorRateExpr></rateErrorModel>
    </CustomCommsDevice>
  </vehicle>
  <vehicle>
    <name>buoy</name>
    <position>10, -20, 0</position>
    <poseSource>zenoh</poseSource>
    <CustomCommsDevice>
      <dccommsId>buoy-ac</dccommsId>
      <mac>2</mac>
      <txChannelId>1</txChannelId>
      <rxChannelId>0</rxChannelId>
      <minPktErrRatio>0.01</minPktErrRatio>
      <pktErrRatioIncPerMeter>1e-05</pktErrRatioIncPerMeter>
    </CustomCommsDevice>
  </vehicle>
  <flow>
    <name>telemetry</name>
    <src>auv-ac</src>
    <dst>2</dst>
    <size>244</size>
    <rate>4</rate>
    <arrival>poisson</arrival>
    <start>5</start>
    <stop>100</stop>
  </flow>
  <flow>
    <src>buoy-ac</src>
    <dst>255</dst>
    <size>32</size>
    <interval>2.5</interval>
  </flow>
</UWSimScene>
"""


def test_native_scene_exact_values() -> None:
    scene, warnings = _load(NATIVE, source="native.xml")
    assert warnings == [
        "native.xml:56: warning: legacy <minPktErrRatio>/<pktErrRatioIncPerMeter> read as rateErrorModel"
        " errorUnit=packet errorRateExpr=0.01+1e-05*m",
    ]
    expected = Scene(
        name="lab",
        source="native.xml",
        simulation=Simulation(duration=120.0, seed=42, clock="realtime", world="lab"),
        tracing=Tracing(class_name="mypkg.tracing:Counter", log_to_file="run.log"),
        channels=(Channel(id=0, prop_s_per_m=0.0006667), Channel(id=1, prop_s_per_m=3.333333333e-9,
                                                                min_prop_s=0.002)),
        vehicles=(
            Vehicle(
                name="auv", position=(0.0, 0.0, 5.0), pose_rate_hz=20.0,
                trajectory=(Waypoint(t=0, x=0, y=0, z=5), Waypoint(t=10, x=50, y=0, z=5),
                            Waypoint(t=20.5, x=50, y=25, z=7.5)),
                devices=(
                    Device(dccomms_id="auv-ac", address=1, tx_channel=0, rx_channel=0, bitrate=1000.0,
                           tx_fifo_bytes=0, intrinsic_tx_s=0.002, intrinsic_rx_s=0.0035, jitter_tx_s=0.0005,
                           jitter_rx_s=0.001, max_distance=500.0, min_distance=1.0,
                           error=ErrorModel(unit="packet", expr="0.001*m"),
                           mac=MacSpec(name="aloha", params={"maxBackoff": "2.5"}),
                           header_bytes=12, max_frame_bytes=256),
                    Device(dccomms_id="auv-rf", address=1, tx_channel=1, rx_channel=1,
                           error=ErrorModel(expr="0")),
                ),
            ),
            Vehicle(name="buoy", position=(10.0, -20.0, 0.0), pose_source="zenoh", devices=(
                Device(dccomms_id="buoy-ac", address=2, tx_channel=1, rx_channel=0,
                       error=ErrorModel(unit="packet", expr="0.01+1e-05*m")),
            )),
        ),
        flows=(
            Flow(name="telemetry", src="auv-ac", dst=2, size=244, interval=0.25, arrival="poisson", start=5.0,
                 stop=100.0),
            Flow(name="flow2", src="buoy-ac", dst=255, size=32, interval=2.5),
        ),
    )
    assert _strip_lines(scene.model_dump()) == _strip_lines(expected.model_dump())
    # every element keeps its line
    assert scene.line == 1 and scene.simulation.line == 2 and scene.tracing.line == 8
    assert [c.line for c in scene.channels] == [12, 13]
    auv, buoy = scene.vehicles
    assert (auv.line, buoy.line) == (15, 47)
    assert [w.line for w in auv.trajectory] == [18, 19, 20]
    assert [d.line for d in auv.devices] == [23, 39]
    assert auv.devices[0].error.line == 34 and auv.devices[0].mac.line == 35
    assert [f.line for f in scene.flows] == [60, 70]
    assert auv.devices[1].half_duplex
    assert not buoy.devices[0].half_duplex


def test_example_scenes_load() -> None:
    warnings: list[str] = []
    two = load_scene(REPO / "scenes/examples/two-nodes.xml", on_warning=warnings.append)
    assert warnings == []
    assert two.world == "two-nodes"
    assert two.simulation == Simulation(line=two.simulation.line, duration=60.0, seed=1, world="two-nodes")
    a, b = two.vehicles
    assert [p - q for p, q in zip(b.position, a.position, strict=True)] == [100.0, 0.0, 0.0]
    assert two.channels[0].prop_s_per_m == pytest.approx(6.667e-4, rel=1e-12)
    assert all(d.bitrate == 1000.0 and d.error.expr == "0" for _, d in two.devices())
    (f,) = two.flows
    assert (f.size, f.interval, f.arrival, f.start, f.stop) == (32, 1.0, "periodic", 0.0, 60.0)
    assert f.src == a.devices[0].dccomms_id and f.dst == b.devices[0].address

    legacy_warnings: list[str] = []
    legacy = load_scene(REPO / "scenes/legacy/prop-errors.xml", on_warning=legacy_warnings.append)
    assert legacy_warnings and all(": warning: " in w for w in legacy_warnings)
    assert len(legacy.devices()) == 2 and legacy.name == "prop-errors"


# ------------------------------------------------------------------------------------- smaller behaviours

def _scene(dev: str = "", veh: str = "", top: str = "", mac: str = "<mac>1</mac>") -> str:
    """A one-device scene; each insertion is one line, so its line number is fixed:
    `dev` at line 10, `veh` at 12, `top` at 14 (device element at 5, dccommsId 6, mac 7)."""
    return "\n".join([
        "<UWSimScene>",                                               # 1
        "  <CustomCommsChannel><id>0</id></CustomCommsChannel>",      # 2
        "  <vehicle>",                                                # 3
        "    <name>a</name>",                                         # 4
        "    <CustomCommsDevice>",                                    # 5
        "      <dccommsId>a-dev</dccommsId>",                         # 6
        f"      {mac}",                                               # 7
        "      <txChannelId>0</txChannelId>",                         # 8
        "      <rxChannelId>0</rxChannelId>",                         # 9
        f"      {dev}",                                               # 10
        "    </CustomCommsDevice>",                                   # 11
        f"    {veh}",                                                 # 12
        "  </vehicle>",                                               # 13
        f"  {top}",                                                   # 14
        "</UWSimScene>",                                              # 15
    ]) + "\n"


NO_LOSS = "<rateErrorModel><errorRateExpr>0</errorRateExpr></rateErrorModel>"


def _device(dev_id: str, mac: int, tx: int = 0, rx: int = 0, extra: str = "") -> str:
    return (f"<CustomCommsDevice><dccommsId>{dev_id}</dccommsId><mac>{mac}</mac>"
            f"<txChannelId>{tx}</txChannelId><rxChannelId>{rx}</rxChannelId>{extra}</CustomCommsDevice>")


def test_minimal_scene_defaults_and_missing_error_model_warning() -> None:
    scene, warnings = _load(_scene())
    assert warnings == ["t.xml:5: warning: no rateErrorModel: assuming no propagation loss"
                        " (the original assumed 0.01*m)"]
    assert scene.name == "scene" and scene.world == "scene"
    (ch,) = scene.channels
    assert ch.prop_s_per_m == pytest.approx(0.66667e-3)
    ((v, d),) = scene.devices()
    assert v.position == (0.0, 0.0, 0.0) and v.pose_source == "scene" and v.pose_rate_hz == 10.0
    assert _strip_lines(d.model_dump()) == _strip_lines(
        Device(dccomms_id="a-dev", address=1, tx_channel=0, rx_channel=0).model_dump())


def test_disabled_device_is_skipped() -> None:
    scene, warnings = _load(_scene(dev="<disable>1</disable><bitrate>ignored-anyway</bitrate>"))
    assert scene.vehicles[0].devices == ()
    assert warnings == ["t.xml:5: warning: <CustomCommsDevice> 'a-dev' is disabled (<disable>), skipped"]
    scene, _ = _load(_scene(dev="<disable>0</disable>" + NO_LOSS))
    assert len(scene.vehicles[0].devices) == 1


def test_same_address_on_different_rx_channels_is_fine() -> None:
    top = ("<CustomCommsChannel><id>1</id></CustomCommsChannel>"
           f"<vehicle><name>b</name>{_device('b-dev', 1, 1, 1, NO_LOSS)}</vehicle>")
    scene, _ = _load(_scene(dev=NO_LOSS, top=top))
    assert [d.address for _, d in scene.devices()] == [1, 1]


def test_rendering_elements_warn_once_each() -> None:
    # AcousticCommsChannel / AcousticCommsDevice are read since issue #5 (tests/test_scene_acoustic.py)
    veh = "<imu><name>i</name><relativeTo>base</relativeTo></imu>"
    top = "<object><name>o</name></object>"
    _, warnings = _load(_scene(dev=NO_LOSS, veh=veh, top=top))
    assert warnings == [
        "t.xml:12: warning: <imu> in <vehicle> ignored (UWSim 3D scene element)",
        "t.xml:14: warning: <object> ignored (UWSim 3D scene element)",
    ]


def test_flow_to_unknown_address_warns() -> None:
    top = "<flow><src>a-dev</src><dst>9</dst><size>8</size><interval>1</interval></flow>"
    scene, warnings = _load(_scene(dev=NO_LOSS, top=top))
    assert scene.flows[0].dst == 9
    assert warnings == ["t.xml:14: warning: flow 'flow1': no device listening on channel 0 has address 9"]


def test_text_with_encoding_declaration_and_bytes() -> None:
    text = '<?xml version="1.0" encoding="ISO-8859-1"?>\n<UWSimScene><simulation><world>caf\u00e9</world>' \
           "</simulation></UWSimScene>\n"
    assert load_scene_text(text).world == "caf\u00e9"
    assert load_scene_text(text.encode("iso-8859-1")).world == "caf\u00e9"


def test_default_warning_goes_to_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    load_scene_text("<UWSimScene><camera/></UWSimScene>", source="s.xml")
    assert capsys.readouterr().err == "s.xml:1: warning: <camera> ignored (UWSim 3D scene element)\n"


def test_scene_error_is_one_line() -> None:
    e = SceneError("f.xml", 3, "bad\nthing")
    assert str(e) == "f.xml:3: bad thing"
    assert (e.source, e.line, e.message) == ("f.xml", 3, "bad thing")


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.xml"
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value) == f"{path}:0: cannot read scene file: No such file or directory"


def test_errors_in_files_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.xml"
    path.write_text(_scene(dev="<bitrate>fast</bitrate>"))
    warnings: list[str] = []
    with pytest.raises(SceneError) as info:
        load_scene(path, on_warning=warnings.append)
    assert str(info.value) == f"{path}:10: bitrate: expected a number, got 'fast'"
    assert warnings == []     # the device never finished loading: no missing-rateErrorModel warning


def test_warnings_above_an_error_are_still_reported() -> None:
    warnings: list[str] = []
    with pytest.raises(SceneError):
        load_scene_text(_scene(veh="<file>x.urdf</file>", top=FLOW.format("").replace("a-dev", "b")),
                        on_warning=warnings.append)
    assert warnings == ["<string>:5: warning: no rateErrorModel: assuming no propagation loss"
                        " (the original assumed 0.01*m)",
                        "<string>:12: warning: <file> in <vehicle> ignored (UWSim 3D scene element)"]


# ------------------------------------------------------------------------------------- bad scenes

FLOW = "<flow><src>a-dev</src><dst>2</dst><size>8</size>{}</flow>"
XXE = """\
<?xml version="1.0"?>
<!DOCTYPE UWSimScene [ <!ENTITY xxe SYSTEM "file:///etc/passwd"> ]>
<UWSimScene>
  <simulation><world>&xxe;</world></simulation>
</UWSimScene>
"""

BAD: list[tuple[str, str, str]] = [
    ("malformed-xml", "<UWSimScene>\n  <vehicle>\n    <name>a</nam>\n  </vehicle>\n</UWSimScene>\n",
     "3: XML syntax error: Opening and ending tag mismatch: name line 3 and nam (column 18)"),
    ("empty-document", "", "1: XML syntax error: Document is empty (column 1)"),
    ("wrong-root", "<?xml version='1.0'?>\n<scene/>\n", "2: root element must be <UWSimScene>, got <scene>"),
    ("unknown-top-element", _scene(dev=NO_LOSS, top="<foo/>"), "14: unknown element <foo> in <UWSimScene>"),
    ("unknown-vehicle-element", _scene(dev=NO_LOSS, veh="<foo>1</foo>"),
     "12: unknown element <foo> in <vehicle>"),
    ("misspelt-device-element", _scene(dev="<bitRate>9</bitRate>"),
     "10: unknown element <bitRate> in <CustomCommsDevice> (did you mean <bitrate>?)"),
    ("non-number", _scene(dev="<bitrate>fast</bitrate>"), "10: bitrate: expected a number, got 'fast'"),
    ("non-integer-mac", _scene(mac="<mac>1.5</mac>"), "7: mac: expected an integer, got '1.5'"),
    ("bitrate-not-positive", _scene(dev="<bitrate>-5</bitrate>"),
     "10: bitrate: must be greater than 0, got -5"),
    ("broadcast-address-as-mac", _scene(mac="<mac>255</mac>"),
     "7: mac: address 255 is the broadcast address"),
    ("mac-out-of-range", _scene(mac="<mac>70000</mac>"), "7: mac: must be at most 65535, got 70000"),
    ("missing-mac", _scene(mac=""), "5: CustomCommsDevice: missing <mac>"),
    ("huge-integer", _scene(mac=f"<mac>{'9' * 5000}</mac>"),
     f"7: mac: expected an integer, got '{'9' * 37}...'"),
    ("expr-injection",
     _scene(dev="<rateErrorModel><errorRateExpr>__import__('os')</errorRateExpr></rateErrorModel>"),
     "10: errorRateExpr: unknown name '__import__' at column 1"
     " (allowed: m, pi, e, exp, log, log10, sqrt, pow, min, max, abs)"),
    ("expr-syntax", _scene(dev="<rateErrorModel><errorRateExpr>6e-13*m^</errorRateExpr></rateErrorModel>"),
     "10: errorRateExpr: unexpected end of expression at column 9"),
    ("error-unit", _scene(dev="<rateErrorModel><errorUnit>nibble</errorUnit><errorRateExpr>0</errorRateExpr>"
                              "</rateErrorModel>"),
     "10: errorUnit: expected bit, byte or packet, got 'nibble'"),
    ("error-model-without-expr", _scene(dev="<rateErrorModel><errorUnit>bit</errorUnit></rateErrorModel>"),
     "10: rateErrorModel: missing <errorRateExpr>"),
    ("legacy-and-new-error-model", _scene(dev=NO_LOSS + "<minPktErrRatio>0.1</minPktErrRatio>"),
     "10: minPktErrRatio: give either <rateErrorModel> or the legacy"
     " <minPktErrRatio>/<pktErrRatioIncPerMeter>, not both"),
    ("undefined-channel",
     _scene(dev=NO_LOSS, top=f"<vehicle><name>b</name>{_device('b-dev', 2, tx=3)}</vehicle>"),
     "14: txChannelId: no CustomCommsChannel with id 3"),
    ("duplicate-channel", _scene(dev=NO_LOSS, top="<CustomCommsChannel><id>0</id></CustomCommsChannel>"),
     "14: duplicate channel id 0 (first at line 2)"),
    ("duplicate-dccommsId",
     _scene(dev=NO_LOSS, top=f"<vehicle><name>b</name>{_device('a-dev', 2)}</vehicle>"),
     "14: duplicate dccommsId 'a-dev' (first at line 6)"),
    ("duplicate-address-on-channel",
     _scene(dev=NO_LOSS, top=f"<vehicle><name>b</name>{_device('b-dev', 1, extra=NO_LOSS)}</vehicle>"),
     "14: mac 1 is already used on rx channel 0 by 'a-dev' (line 7)"),
    ("duplicate-vehicle", _scene(dev=NO_LOSS, top="<vehicle><name>a</name></vehicle>"),
     "14: duplicate vehicle name 'a' (first at line 4)"),
    ("duplicate-element", _scene(dev="<bitrate>1</bitrate><bitrate>2</bitrate>"),
     "10: duplicate <bitrate> in <CustomCommsDevice> (first at line 10)"),
    ("value-with-children", _scene(dev="<bitrate><x>1</x></bitrate>"),
     "10: <bitrate> holds a value, not elements (found <x>)"),
    ("min-over-max-distance", _scene(dev="<maxDistance>10</maxDistance><minDistance>50</minDistance>"),
     "10: minDistance 50 is larger than maxDistance 10"),
    ("negative-rx-delay", _scene(dev="<intrinsicDelay><rx>-1</rx></intrinsicDelay>"),
     "10: intrinsicDelay/rx: must be at least 0, got -1"),
    ("mac-protocol-without-name",
     _scene(dev="<macProtocol><maxBackoffSlots>4</maxBackoffSlots></macProtocol>"),
     "10: macProtocol: missing <name>"),
    ("position-two-numbers", _scene(dev=NO_LOSS, veh="<position>1 2</position>"),
     "12: position: expected 'x y z' or <x>, <y>, <z> children, got '1 2'"),
    ("position-missing-z", _scene(dev=NO_LOSS, veh="<position><x>1</x><y>2</y></position>"),
     "12: position: missing <z>"),
    ("waypoints-not-increasing",
     _scene(dev=NO_LOSS, veh='<trajectory><waypoint t="5" x="0" y="0" z="0"/>'
                            '<waypoint t="5" x="1" y="0" z="0"/></trajectory>'),
     "12: waypoint: times must increase (t=5 after t=5)"),
    ("waypoint-missing-z", _scene(dev=NO_LOSS, veh='<trajectory><waypoint t="0" x="0" y="0"/></trajectory>'),
     "12: waypoint: missing z (attribute or element)"),
    ("pose-source", _scene(dev=NO_LOSS, veh="<poseSource>ros</poseSource>"),
     "12: poseSource: expected scene or zenoh, got 'ros'"),
    ("flow-unknown-src",
     _scene(dev=NO_LOSS, top=FLOW.format("<interval>1</interval>").replace("a-dev", "ghost")),
     "14: src: no device with dccommsId 'ghost'"),
    ("flow-src-disabled", _scene(dev="<disable>1</disable>", top=FLOW.format("<interval>1</interval>")),
     "14: src: device 'a-dev' is disabled (line 5)"),
    ("flow-rate-and-interval", _scene(dev=NO_LOSS, top=FLOW.format("<interval>1</interval><rate>2</rate>")),
     "14: flow: give either <interval> or <rate>, not both"),
    ("flow-neither-rate-nor-interval", _scene(dev=NO_LOSS, top=FLOW.format("")),
     "14: flow: missing <interval> (s) or <rate> (frames/s)"),
    ("flow-zero-rate", _scene(dev=NO_LOSS, top=FLOW.format("<rate>0</rate>")),
     "14: rate: must be greater than 0, got 0"),
    ("flow-stop-before-start",
     _scene(dev=NO_LOSS, top=FLOW.format("<interval>1</interval><start>10</start><stop>5</stop>")),
     "14: stop: must be after start (stop 5, start 10)"),
    ("flow-too-big", _scene(dev=NO_LOSS + "<headerBytes>16</headerBytes>",
                            top=FLOW.format("<interval>1</interval>").replace("<size>8", "<size>2040")),
     "14: size: 2040 + headerBytes 16 = 2056 bytes exceeds maxFrameBytes 2048 of device 'a-dev'"),
    ("flow-larger-than-fifo", _scene(dev=NO_LOSS + "<txFifoSize>100</txFifoSize>",
                                     top=FLOW.format("<interval>1</interval>").replace("<size>8", "<size>101")),
     "14: size: 101 bytes on air exceed txFifoSize 100 of device 'a-dev' (every frame would be refused: it could"
     " never wait there)"),
    ("flow-arrival", _scene(dev=NO_LOSS, top=FLOW.format("<interval>1</interval><arrival>burst</arrival>")),
     "14: arrival: expected periodic or poisson, got 'burst'"),
    ("flow-dst-range",
     _scene(dev=NO_LOSS, top=FLOW.format("<interval>1</interval>").replace("<dst>2", "<dst>-1")),
     "14: dst: must be at least 0, got -1"),
    ("duplicate-flow-name",
     _scene(dev=NO_LOSS, top=2 * FLOW.format("<name>f</name><interval>1</interval>")),
     "14: duplicate flow name 'f' (first at line 14)"),
    ("unexpected-attribute", _scene(dev=NO_LOSS, top='<flow rate="2"/>'),
     "14: unexpected attribute 'rate' on <flow>"),
    ("stray-text", _scene(dev=NO_LOSS, veh="oops"), "12: unexpected text 'oops' in <vehicle>"),
    ("clock", _scene(dev=NO_LOSS, top="<simulation><clock>fast</clock></simulation>"),
     "14: clock: expected virtual or realtime, got 'fast'"),
    ("duration", _scene(dev=NO_LOSS, top="<simulation><duration>0</duration></simulation>"),
     "14: duration: must be greater than 0, got 0"),
    ("world-not-a-key-chunk", _scene(dev=NO_LOSS, top="<simulation><world>a/b</world></simulation>"),
     "14: world: must be one Zenoh key chunk (no '/', '*', '$', '?', '#' or spaces), got 'a/b'"),
    ("two-simulation-sections", _scene(dev=NO_LOSS, top="<simulation/><simulation/>"),
     "14: duplicate <simulation> in <UWSimScene> (first at line 14)"),
    ("external-entity", XXE, "4: entity references are not supported (&xxe;)"),
]


@pytest.mark.parametrize(("text", "expected"), [(t, e) for _, t, e in BAD], ids=[i for i, _, _ in BAD])
def test_bad_scene(text: str, expected: str) -> None:
    with pytest.raises(SceneError) as info:
        load_scene_text(text, source="bad.xml", on_warning=lambda _: None)
    assert str(info.value) == f"bad.xml:{expected}"
    assert "\n" not in str(info.value)
    assert info.value.source == "bad.xml" and info.value.line == int(expected.split(":")[0])


def test_scene_format_doc_examples_load() -> None:
    """The complete scenes in docs/scene-format.md load without warnings; the first is two-nodes.xml."""
    doc = (REPO / "docs/scene-format.md").read_text()
    blocks = [b.split("```", 1)[0] for b in doc.split("```xml\n")[1:]]
    scenes = [b for b in blocks if "<UWSimScene>" in b]
    assert len(scenes) == 2
    for text in scenes:
        _, warnings = _load(text)
        assert warnings == []
    example = (REPO / "scenes/examples/two-nodes.xml").read_text()
    body = example[example.index("<UWSimScene>"):]
    assert scenes[0].endswith(body)
