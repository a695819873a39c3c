"""Every scene instantiation the original's run scripts make (dccomms_examples, dcentelles; issue #39.2), 42 here
(docs/paper-twinbot.md lists them by script, and why the issue's 33 is not what the scripts make), made as the
scripts make them: their `sed` substitutions reproduced from reading them (cited per case), then
loaded and run for a few simulated seconds, or refused with the original's own reason.  The scenes carry no
licence, so they are read from a clone of the public repository (UWSIMNET_DCCOMMS_EXAMPLES: a git directory;
skipped without one), never copied here."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.scene.load import load_scene_text

REPO = Path(os.environ.get("UWSIMNET_DCCOMMS_EXAMPLES", "/work/.mirror/dcentelles+dccomms_examples/repo"))
HEAD = "1c03392"            # the last commit (2020); the netsim_twinbot_* scenes were deleted in 7431fee
TWINBOT_DCMAC = "cdad6eb"   # "status after twinbot mac comparative" (2019-07-24): their last version
PERF = ["mac_performance", "mac_performance_large", "mac_performance_square", "mac_performance_square_120x120",
        "mac_performance_square_60x60"]


def show(rev: str, path: str) -> str:
    return subprocess.run(["git", "--git-dir", str(REPO), "show", f"{rev}:{path}"], check=True,
                          capture_output=True, text=True).stdout


def perf(scene: str, proto: str, speed: str, slots: str = "4") -> str:
    """testing/mac_performance.sh:264-297 (mac_performance_transport.sh is the same there), as gtest.sh:55
    calls it with protocols "aloha sfama dcmac" (gtest.sh:4-8) and ac|rf (mac_performance.sh:17-25)."""
    s = show(HEAD, f"testing/scenes/{scene}.xml")
    if proto == "dcmac":
        pb, lib = "DcMacPacketBuilder", "<libPath>/build/modules/umci/libumci.so</libPath>"
    else:
        pb, lib = "VariableLength2BPacketBuilder", ""
        s = s.replace("<name></name>", f"<name>{proto}</name>")
    s = s.replace("<maxDistance>15</maxDistance>", "<maxDistance>100</maxDistance>")
    s = s.replace("<maxBackoffSlots></maxBackoffSlots>", f"<maxBackoffSlots>{slots}</maxBackoffSlots>")
    s = s.replace("propSpeedValue", "0.666" if speed == "ac" else "3.333333333e-06")
    return s.replace("packetbuilder", pb).replace("builderlibpath", lib)


def twinbot(proto: str) -> str:
    """testing/mac_twinbot.sh:280-313 (twinbot.xml; long link channel 0 at 100 m, short link channel 1 at 15 m)."""
    s = show(HEAD, "testing/scenes/twinbot.xml")
    if proto == "nomac":
        pb, lib = "VariableLength2BPacketBuilder", ""
    elif proto == "dcmac":
        pb, lib = "DcMacPacketBuilder", "<libPath>/build/libdccomms_examples_packets.so</libPath>"
    else:
        s = s.replace("<name></name>", f"<name>{proto}</name>")
        pb, lib = "VariableLength2BPacketBuilder", ""
    for k, v in (("packetbuilder", pb), ("builderlibpath", lib), ("longLinkMaxRange", "100"),
                 ("shortLinkMaxRange", "15"), ("shortLinkChannel", "1"), ("longLinkChannel", "0")):
        s = s.replace(k, v)
    return s


def oceans19(proto: str) -> str:
    """testing/mac_oceans19.sh:257-266: netsim_oceans19.xml for `mac`, netsim_oceans19_nomac.xml otherwise."""
    return show(HEAD, "testing/scenes/" + ("netsim_oceans19.xml" if proto == "mac" else "netsim_oceans19_nomac.xml"))


def dcmac_scene(name: str) -> str:
    """mac_twinbot.sh:267-287 at 3cfb74d (netsim_twinbot_dcmac) and mac_performance.sh:258-280 at cdad6eb
    (..._4slaves): `packetslib` and `propSpeedValue` replaced as sed does (`propSpeedValue1` -> `0.6661`)."""
    s = show(TWINBOT_DCMAC, f"testing/scenes/{name}.xml").replace("packetslib", "/build/libpackets.so")
    return s.replace("propSpeedValue", "0.666")


def mac_scene(name: str, proto: str) -> str:
    """The same scripts' other branch (mac_twinbot.sh:278-287 at 3cfb74d; mac_performance.sh at 20da065-4003191
    for ..._4slaves): `<name></name>` becomes the protocol, then `propSpeedValue` as above."""
    s = show(TWINBOT_DCMAC, f"testing/scenes/{name}.xml").replace("<name></name>", f"<name>{proto}</name>")
    return s.replace("propSpeedValue", "0.666")


CASES = ([(f"perf/{sc}/{p}/{v}", lambda sc=sc, p=p, v=v: perf(sc, p, v))
          for sc in PERF for p in ("aloha", "sfama", "dcmac") for v in ("ac", "rf")]
         + [(f"twinbot/{p}", lambda p=p: twinbot(p)) for p in ("nomac", "dcmac", "aloha", "sfama")]
         + [(f"oceans19/{p}", lambda p=p: oceans19(p)) for p in ("mac", "nomac")]
         + [("netsim_twinbot_dcmac", lambda: dcmac_scene("netsim_twinbot_dcmac")),
            ("netsim_twinbot_dcmac_4slaves", lambda: dcmac_scene("netsim_twinbot_dcmac_4slaves"))]
         + [(f"{n}/{p}", lambda n=n, p=p: mac_scene(n, p))
            for n in ("netsim_twinbot_mac", "netsim_twinbot_mac_4slaves") for p in ("aloha", "sfama")])


@pytest.mark.skipif(not REPO.exists(), reason="no clone of dcentelles/dccomms_examples (UWSIMNET_DCCOMMS_EXAMPLES)")
@pytest.mark.parametrize("name, make", CASES, ids=[c[0] for c in CASES])
def test_every_instantiation_loads_and_runs(name, make):
    scene = load_scene_text(make(), f"{name}.xml", on_warning=lambda _w: None)
    net = Network(scene, seed=1, duration=3.0)
    net.run()
    assert net.modems


@pytest.mark.skipif(not REPO.exists(), reason="no clone of dcentelles/dccomms_examples (UWSIMNET_DCCOMMS_EXAMPLES)")
def test_the_dcmac_scene_delivers_frames_with_dcmac():
    """netsim_twinbot_dcmac_4slaves as mac_performance.sh:342-370 at cdad6eb drives it: four slaves (addresses 1-4)
    send to the master (0), the master to slave 1; example4's apps are flows here."""
    flows = "".join(
        f"<flow><name>{dev}</name><src>{dev}</src><dst>{dst}</dst><size>20</size><interval>5</interval>"
        f"<start>10</start><stop>60</stop></flow>"
        for dev, dst in (("bluerov2_s100", 0), ("bluerov2_f_s100", 0), ("bluerov2_f2_s100", 0),
                         ("bluerov2_f3_s100", 0), ("g500_s100", 1)))
    text = dcmac_scene("netsim_twinbot_dcmac_4slaves").replace("</UWSimScene>", flows + "</UWSimScene>")
    scene = load_scene_text(text, "4slaves.xml", on_warning=lambda _w: None)
    assert {d.mac.name for _, d in scene.devices()} == {"dcmac"}
    net = Network(scene, seed=1, duration=120.0)
    recs: list[dict] = []
    net.tracer.add(recs.append)
    net.run()
    for flow in ("bluerov2_s100", "bluerov2_f_s100", "bluerov2_f2_s100", "bluerov2_f3_s100", "g500_s100"):
        sent = {r["seq"] for r in recs if r["ev"] == "enq" and r["flow"] == flow}
        got = {r["seq"] for r in recs if r["ev"] == "rx" and r["flow"] == flow and r["kind"] == "data"}
        assert len(sent) == 10 and got == sent, flow
    assert {r["size"] for r in recs if r["ev"] == "tx" and r["kind"] == "data"} == {26}       # 20 + 6 (DcMacPacket)


@pytest.mark.skipif(not REPO.exists(), reason="no clone of dcentelles/dccomms_examples (UWSIMNET_DCCOMMS_EXAMPLES)")
def test_the_count_docs_paper_twinbot_gives():
    """docs/paper-twinbot.md lists the 42 by script: 30 + 4 + 2 + 2 + 4, 13 with DcMacPacketBuilder, 10 aloha scenes
    given maxBackoffSlots; counted here from the scenes the substitutions make, not from the case names."""
    groups: dict[str, int] = {}
    for name, _ in CASES:
        key = name.split("/")[0].removesuffix("_4slaves")
        groups[key] = groups.get(key, 0) + 1
    texts = [make() for _, make in CASES]
    dcmac = sum("DcMacPacketBuilder" in t for t in texts)
    aloha_slots = sum("<name>aloha</name>" in t and "<maxBackoffSlots>4</maxBackoffSlots>" in t for t in texts)
    doc = (Path(__file__).resolve().parents[1] / "docs" / "paper-twinbot.md").read_text(encoding="utf-8")
    counts = (groups["perf"], groups["twinbot"], groups["oceans19"], groups["netsim_twinbot_dcmac"],
              groups["netsim_twinbot_mac"])
    assert counts == (30, 4, 2, 2, 4) and (dcmac, aloha_slots) == (13, 10)
    assert f"{' + '.join(map(str, counts))} = {len(CASES)}; {dcmac} of them use `DcMacPacketBuilder`" in doc
    assert f"{aloha_slots} put `maxBackoffSlots` into an" in doc
