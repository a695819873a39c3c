"""fjåge's JSON lines as the gateway reads and writes them, checked against fjåge's protocol document
(docs/protocol.qmd at org-arl/fjage 09c621d) and against fjagepy 2.2.0, the real client library."""

from __future__ import annotations

import json

import pytest

from uwsimnet_zenoh.bridges import unet_fjage as fj

fjagepy = pytest.importorskip("fjagepy", reason="fjagepy comes with unetpy (dev extra)")
from fjagepy import JSONMessage  # noqa: E402


def test_lines_end_with_lf_cr_or_crlf_and_may_come_in_pieces():
    r = fj.LineReader()
    assert r.feed(b'{"a": 1}\r\n{"b"') == [{"a": 1}]
    assert r.feed(b': 2}\r{"c": 3}\n\n') == [{"b": 2}, {"c": 3}]
    bad = r.feed(b'{nope\n[1]\n{"d": 4}\n')
    assert [type(x).__name__ for x in bad] == ["ProtocolError", "ProtocolError", "dict"]
    with pytest.raises(fj.ProtocolError):
        fj.LineReader(max_line=100).feed(b"x" * 101)


def test_byte_arrays_as_the_protocol_document_and_fjagepy_write_them():
    # protocol.qmd, "JSON message with byte array to transmit a Datagram": base64 "[B" of "hello world!"
    assert fj.read_bytes({"clazz": "[B", "data": "aGVsbG8gd29ybGQh"}) == b"hello world!"
    # its float example "[F" P4AAAD+AAAA/gAAA is three floats; not bytes, read as numbers then refused
    with pytest.raises(ValueError):
        fj.read_bytes({"clazz": "[F", "data": "AACAPwAAgD8AAIA/"})           # 1.0f x3 little-endian: not ints
    assert fj.read_bytes([1, 2, 255, -1]) == b"\x01\x02\xff\xff"
    for bad in ([256], ["a"], [True], {"clazz": "[X", "data": ""}, "abc"):
        with pytest.raises(ValueError):
            fj.read_bytes(bad)


def test_fjagepy_reads_what_the_gateway_writes():
    import unetpy  # noqa: F401 - registers UnetStack's message classes with fjagepy

    data = bytes(range(256))
    line = fj.send("org.arl.unet.DatagramNtf", {"perf": "INFORM", "recipient": "#phy__ntf", "sender": "phy",
                                                "from": 31, "to": 0, "protocol": 32, "data": fj.byte_array(data)})
    assert line.endswith(b"\n") and b"\n" not in line[:-1]
    m = JSONMessage(line.decode().strip())
    assert m.action == "send" and m.relay is False
    msg = m.message
    assert type(msg).__name__ == "DatagramNtf" and msg.recipient.is_topic() and msg.recipient.name == "phy__ntf"
    assert bytes(x & 0xFF for x in msg.data) == data and min(msg.data) == -128     # Java's signed bytes
    r = JSONMessage(fj.response({"id": "q1", "action": "agentsForService"}, agentIDs=["phy"]).decode().strip())
    assert r.id == "q1" and r.inResponseTo == "agentsForService" and [a.name for a in r.agentIDs] == ["phy"]


def test_the_gateway_reads_what_fjagepy_writes():
    from unetpy import DatagramReq

    req = DatagramReq(to=31, protocol=32, data=list(b"\x00hi\xff"))
    req.sender = fjagepy.AgentID("gateway-1")
    req.recipient = fjagepy.AgentID("phy")
    (obj,) = fj.LineReader().feed(JSONMessage.createSend(req, relay=True).to_json().encode() + b"\n")
    m = obj["message"]
    assert m["clazz"] == "org.arl.unet.DatagramReq" and m["data"]["perf"] == "REQUEST"
    assert fj.read_bytes(m["data"]["data"]) == b"\x00hi\xff" and m["data"]["recipient"] == "phy"
    reply = json.loads(fj.reply(m["data"], "org.arl.fjage.Message", "AGREE", "phy"))
    assert reply["message"]["data"]["inReplyTo"] == req.msgID and reply["message"]["data"]["recipient"] == "gateway-1"
