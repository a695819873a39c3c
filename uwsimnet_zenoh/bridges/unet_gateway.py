"""A UnetStack node in front of one modem: fjåge's JSON protocol on a TCP port of its own, so `unetpy`,
`unet.js` and the fjåge gateways run unmodified against a simulated (or, after a HIL swap, real) modem
(docs/unetstack.md).

The gateway is a client of the world over Zenoh through `uwsimnet_gli.Modem` (the one wire, nothing of the
simulator): whoever serves the modem, the simulator or a real driver, looks the same to it.  It plays three
UnetStack agents: `node` (NODE_INFO: address, nodeName, location from the pose table), `arp`
(ADDRESS_RESOLUTION: the world's vehicle names and modem ids) and `phy` (PHYSICAL and DATAGRAM: DatagramReq,
TxFrameReq, their AGREE / TxFrameNtf / DatagramFailureNtf, and DatagramNtf / RxFrameNtf on its topic).

On air a frame carries one header byte before the payload (as UnetStack's own PHY header carries the
protocol): bits 0-5 the protocol, bit 6 set for a datagram (DatagramReq -> DatagramNtf), bit 7 set for a
CONTROL frame (TxFrameReq type 1); without bit 6 it arrives as an RxFrameNtf.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections import Counter, deque
from typing import Any

import zenoh
from uwsimnet_gli import BROADCAST, Modem, World
from uwsimnet_gli.records import Frame, Status
from uwsimnet_gli.wire import MAX_ADDRESS, CodecError, decode_pose

from ..drivers._aio import LoopThread, ServerClient, TcpServer
from . import unet_fjage as fj

log = logging.getLogger("uwsimnet.bridges.unet")

UNET_BROADCAST = 0
"""UnetStack's broadcast address (Address.BROADCAST); the simulator's is 255."""
DATAGRAM_BIT, CONTROL_BIT, PROTOCOL_MASK = 0x40, 0x80, 0x3F
HEADER_BYTES = 1
CONTROL, DATA = 1, 2                    # UnetStack frame types (Physical.CONTROL, Physical.DATA)
REPLY_DELAY_S = 0.01
"""Answers to requests leave this long after the request: fjagepy 2.2.0 registers the waiter of a reply
only after sending the request (Gateway._msg_tx_rx, Gateway.request), so an answer that comes back
before that is lost (a KeyError or a timeout in the application).  Later writes queue behind it."""
MAX_BACKLOG = 1 << 20
"""Bytes waiting for a client that does not read (in the transport and the socket's send queue:
`ServerClient.waiting`); past it the client is closed (one log line)."""
STALL_S = 30.0
"""A client that takes none of what waits for it for this long (wall s) is closed too (one log line): its
requests may never reach us to make more wait (a client's TCP backing off while it does not read)."""

S = "org.arl.unet.Services."
AGENTS: dict[str, tuple[str, ...]] = {
    "node": (S + "NODE_INFO",),
    "arp": (S + "ADDRESS_RESOLUTION",),
    "phy": (S + "PHYSICAL", S + "DATAGRAM"),
}
TYPES = {"node": "org.arl.unet.nodeinfo.NodeInfo", "arp": "org.arl.unet.addr.AddressResolution",
         "phy": "uwsimnet.UnetGatewayPhy"}
TITLES = {"node": "Node information", "arp": "Address resolution", "phy": "Physical layer (uwsimnet modem)"}
NODE_P, DGRAM_P, PHY_P, CHAN_P = ("org.arl.unet.nodeinfo.NodeInfoParam.", "org.arl.unet.DatagramParam.",
                                  "org.arl.unet.phy.PhysicalParam.", "org.arl.unet.phy.PhysicalChannelParam.")


def header(protocol: int, datagram: bool, control: bool) -> int:
    return (protocol & PROTOCOL_MASK) | (DATAGRAM_BIT if datagram else 0) | (CONTROL_BIT if control else 0)


class UnetGateway:
    """Serve modem `modem_id` of `world` as a UnetStack node on TCP `host:port` (0: a free port)."""

    def __init__(self, world: World, modem_id: str, host: str = "127.0.0.1", port: int = 0, *,
                 wait: float = 10.0) -> None:
        self.world = world
        self.id = modem_id
        self.host = host
        self.port = port
        self.wait = wait
        self.counters: Counter[str] = Counter()
        self.address = -1
        self.vehicle: str | None = None
        self.bitrate = float("nan")
        self.mtu = 0
        self.location: list[float] | None = None
        self.names: dict[str, int] = {}
        self.closing = False
        self.clients: list[_Client] = []
        self._pending: dict[int, tuple[_Client, dict[str, Any], bool]] = {}   # tag -> client, request, frame?
        self._notified: set[int] = set()
        self._io = LoopThread(f"uwsimnet-unet-{modem_id}")
        self._server: TcpServer | None = None
        self._pose_sub: Any = None
        self._lock = threading.Lock()
        self.modem: Modem | None = None

    # -- lifecycle -----------------------------------------------------------------------------------
    def start(self) -> UnetGateway:
        """Wait until someone serves the modem, read what it is, then listen."""
        self.modem = Modem(self.world, self.id, buffer=0, on_receive=self._zrx, on_status=self._zstatus)
        if self.modem.wait_kind(timeout=self.wait) is None:
            raise RuntimeError(f"{self.id}: no simulator or driver serves this modem in world {self.world.name!r}")
        self.refresh()
        self.modem.on_kind(lambda _k: threading.Thread(target=self.refresh, daemon=True).start())
        self._io.start()
        self._io.submit(self._listen)
        return self

    def _listen(self) -> None:
        self._server = TcpServer(self._io.loop, lambda: _Client(self), self.host, self.port)
        self.port = self._server.port

    def close(self) -> None:
        self._io.shutdown(self._close)
        if self._pose_sub is not None:
            with contextlib.suppress(Exception):
                self._pose_sub.undeclare()
        if self.modem is not None:
            self.modem.close()

    async def _close(self) -> None:
        self.closing = True
        if self._server is not None:
            self._server.close()
        for c in list(self.clients):
            c.write(b'{"alive": false}\n')
            c.close()
        await asyncio.sleep(0.05)

    def __enter__(self) -> UnetGateway:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def refresh(self) -> None:
        """Address, data rate and MTU from the modem's info (its server's: the simulator or a driver);
        vehicle, names and the first location from the world's state; then follow the vehicle's poses."""
        assert self.modem is not None
        deadline = time.monotonic() + self.wait
        while True:         # during a swap the one that leaves may still answer: wait for the one that serves
            info = self.modem.info(timeout=min(2.0, self.wait)) or {}
            if info.get("kind") == self.modem.kind or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        state: dict[str, Any] = {}
        with contextlib.suppress(Exception):
            state = self.world.control("state", timeout=self.wait)
        modems = state.get("modems") or {}
        me = modems.get(self.id) or {}
        names: dict[str, int] = {}
        for dev, m in modems.items():
            if isinstance(m, dict) and isinstance(m.get("address"), int):
                names[dev] = m["address"]
                if isinstance(m.get("vehicle"), str):
                    names.setdefault(m["vehicle"], m["address"])
        address = info.get("address", me.get("address"))
        before = self.address
        with self._lock:
            self.address = int(address) if isinstance(address, int) else -1
            self.vehicle = info.get("vehicle") or me.get("vehicle")
            if isinstance(info.get("bitrate"), int | float):
                self.bitrate = float(info["bitrate"])
            frame = int(info.get("max_frame_bytes") or 2048) - int(info.get("header_bytes") or 0)
            self.mtu = max(0, frame - HEADER_BYTES)
            self.names = names
            v = (state.get("vehicles") or {}).get(self.vehicle) or {}
            if isinstance(v.get("p"), list):
                self.location = [float(x) for x in v["p"]]
            elif isinstance(info.get("position"), list):
                self.location = [float(x) for x in info["position"]]
        if self.names and self.vehicle and self.vehicle in self.names and self.names[self.vehicle] != self.address:
            self.names[self.vehicle] = self.address            # a real modem answers with its own address
        if self._pose_sub is None and self.vehicle:
            self._pose_sub = self.world.session.declare_subscriber(self.world.keys.pose(self.vehicle), self._zpose)
        if before >= 0 and self.address != before:         # e.g. a real modem took over: apps follow
            log.warning("%s: address %d -> %d (%s)", self.id, before, self.address, self.modem.kind)
            self._io.call(self.publish, "#node__ntf", fj.send("org.arl.unet.ParamChangeNtf", {
                "perf": "INFORM", "recipient": "#node__ntf", "sender": "node",
                "paramValues": {NODE_P + "address": self.address}}))
        if self.address == BROADCAST or self.address == UNET_BROADCAST:
            log.warning("%s: address %d is a broadcast address in UnetStack or here", self.id, self.address)

    @property
    def node_name(self) -> str:
        return self.vehicle or self.id

    def info(self) -> dict[str, Any]:
        return {"id": self.id, "port": self.port, "address": self.address, "clients": len(self.clients),
                "counters": dict(self.counters)}

    # -- from Zenoh (its threads): hand over to the loop ---------------------------------------------
    def _zrx(self, f: Frame) -> None:
        self._io.call(self._rx, f)

    def _zstatus(self, st: Status) -> None:
        if st.tag is not None:
            self._io.call(self._status, st)

    def _zpose(self, sample: zenoh.Sample) -> None:
        try:
            p = decode_pose(sample.payload.to_bytes())
        except CodecError:
            return
        with self._lock:
            self.location = [float(x) for x in p.p]

    # -- to clients (loop thread) ----------------------------------------------------------------------
    def publish(self, recipient: str, data: bytes) -> None:
        for c in list(self.clients):
            if c.wants is None or recipient in c.wants:
                c.write(data)

    def _rx(self, f: Frame) -> None:
        if not f.data:
            self.counters["rx_empty"] += 1
            return
        to = UNET_BROADCAST if f.dst == BROADCAST else f.dst
        if to not in (self.address, UNET_BROADCAST):
            self.counters["rx_not_for_me"] += 1
            return
        h, payload = f.data[0], f.data[HEADER_BYTES:]
        datagram = bool(h & DATAGRAM_BIT)
        fields: dict[str, Any] = {
            "perf": "INFORM", "recipient": "#phy__ntf", "sender": "phy",
            "from": f.src, "to": to, "protocol": h & PROTOCOL_MASK, "data": fj.byte_array(payload),
            "rxTime": _us(f.t_rx), "txTime": _us(f.t_tx)}
        if datagram:
            clazz = "org.arl.unet.DatagramNtf"
        else:
            clazz = "org.arl.unet.phy.RxFrameNtf"
            fields["type"] = CONTROL if h & CONTROL_BIT else DATA
        self.counters["rx"] += 1
        self.publish("#phy__ntf", fj.send(clazz, fields))

    def _status(self, st: Status) -> None:
        """TxFrameNtf at the end of transmission; with `reliability` true, DatagramDeliveryNtf once the
        addressee acknowledged (a MAC or modem with ACKs), else DatagramFailureNtf; a frame the modem
        dropped ends with DatagramFailureNtf.  One notification per request."""
        route = self._pending.get(st.tag) if st.tag is not None else None
        if route is None:
            return
        client, req, frame = route
        final = st.event in ("sent", "acked", "failed", "dropped")
        if st.tag not in self._notified:
            ntf: bytes | None = None
            if req["reliable"] and st.event == "acked":
                ntf = fj.reply(req, "org.arl.unet.DatagramDeliveryNtf", "INFORM", "phy", to=req["to"])
            elif req["reliable"] and final:
                why = "noack: nothing acknowledges frames on this modem" if st.event == "sent" else \
                    st.reason or st.event
                ntf = fj.reply(req, "org.arl.unet.DatagramFailureNtf", "FAILURE", "phy", reason=why, to=req["to"])
            elif not req["reliable"] and st.event in ("sent", "transmitted", "acked"):
                fields = {"txTime": _us(st.t), "type": req["type"] if frame else DATA}
                if frame:
                    fields.update({"to": req["to"], "protocol": req["protocol"]})
                ntf = fj.reply(req, "org.arl.unet.phy.TxFrameNtf", "INFORM", "phy", **fields)
            elif st.event in ("failed", "dropped"):
                ntf = fj.reply(req, "org.arl.unet.DatagramFailureNtf", "FAILURE", "phy",
                               reason=st.reason or st.event, to=req["to"])
            if ntf is not None:
                self._notified.add(st.tag)
                self.counters[f"ntf_{st.event}"] += 1
                client.write(ntf)
        if final:
            self._pending.pop(st.tag, None)
            self._notified.discard(st.tag)

    # -- requests (loop thread) ----------------------------------------------------------------------
    def action(self, c: _Client, obj: dict[str, Any]) -> None:
        act = obj.get("action")
        if "alive" in obj and act is None:
            if obj.get("alive") is False:
                c.close()
            return
        if act == "send":
            m = obj.get("message")
            if not isinstance(m, dict) or not isinstance(m.get("clazz"), str) or not isinstance(m.get("data"), dict):
                return c.refuse_line("a send action without a message {clazz, data}")
            return self.message(c, m["clazz"], m["data"])
        if act == "wantsMessagesFor":
            ids = obj.get("agentIDs")
            c.wants = {str(a) for a in ids} if isinstance(ids, list) and ids else None
            return None
        svc = obj.get("service")
        if act == "agents":
            c.answer(fj.response(obj, agentIDs=list(AGENTS), agentTypes=[TYPES[a] for a in AGENTS]))
        elif act == "services":
            c.answer(fj.response(obj, services=sorted({s for v in AGENTS.values() for s in v})))
        elif act == "agentForService":
            found = [a for a, v in AGENTS.items() if svc in v]
            c.answer(fj.response(obj, **({"agentID": found[0]} if found else {})))
        elif act == "agentsForService":
            c.answer(fj.response(obj, agentIDs=[a for a, v in AGENTS.items() if svc in v]))
        elif act == "containsAgent":
            c.answer(fj.response(obj, answer=str(obj.get("agentID")) in AGENTS))
        elif act == "auth":
            c.answer(fj.response(obj, auth=True))
        elif act == "shutdown":
            log.warning("%s: a client asked to shut the node down; ignored (stop the bridge instead)", self.id)
        else:
            self.counters["bad_action"] += 1
            log.warning("%s: unknown action %r from %s; answered empty", self.id, act, c.peer)
            c.answer(fj.response(obj))
        return None

    def message(self, c: _Client, clazz: str, m: dict[str, Any]) -> None:
        to = str(m.get("recipient") or "")
        name = clazz.rsplit(".", 1)[-1]
        if to.startswith("#"):
            return                      # a message to a topic: no agent here subscribes to clients' topics
        if to not in AGENTS:
            self.counters["no_agent"] += 1
            log.warning("%s: %s for agent %r, which this node does not have; refused", self.id, name, to)
            c.answer(fj.reply(m, "org.arl.unet.RefuseRsp", "REFUSE", to or "node",
                             reason=f"no agent {to!r} on this node (agents: {', '.join(AGENTS)})"))
            return
        if name == "ParameterReq":
            c.answer(self.parameters(to, m))
        elif to == "arp" and name == "AddressResolutionReq":
            addr = self.names.get(str(m.get("name")))
            if addr is None:
                c.answer(fj.reply(m, "org.arl.unet.RefuseRsp", "REFUSE", to, reason=f"unknown host {m.get('name')!r}"))
            else:
                c.answer(fj.reply(m, "org.arl.unet.addr.AddressResolutionRsp", "INFORM", to, name=m.get("name"),
                                 address=addr))
        elif to == "phy" and name in ("DatagramReq", "TxFrameReq"):
            self.transmit(c, m, frame=name == "TxFrameReq")
        else:
            self.counters["not_understood"] += 1
            log.warning("%s: %s (%s) to %s is not understood here; answered NOT_UNDERSTOOD", self.id, name,
                        m.get("perf"), to)
            c.answer(fj.reply(m, "org.arl.fjage.Message", "NOT_UNDERSTOOD", to))

    def transmit(self, c: _Client, m: dict[str, Any], *, frame: bool) -> None:
        def refuse(why: str) -> None:
            self.counters["tx_refused"] += 1
            c.answer(fj.reply(m, "org.arl.unet.RefuseRsp", "REFUSE", "phy", reason=why))
        try:
            data = fj.read_bytes(m.get("data"))
        except ValueError as e:
            return refuse(str(e))
        to, protocol, ftype = m.get("to", UNET_BROADCAST), m.get("protocol", 0), m.get("type", DATA)
        if not _int(to) or not 0 <= to <= MAX_ADDRESS:
            return refuse(f"to must be an address 0..{MAX_ADDRESS} (0 = broadcast), got {to!r}")
        if not _int(protocol) or not 0 <= protocol <= PROTOCOL_MASK:
            return refuse(f"protocol must be 0..{PROTOCOL_MASK}, got {protocol!r}")
        if ftype not in (CONTROL, DATA):
            return refuse(f"type must be {CONTROL} (CONTROL) or {DATA} (DATA), got {ftype!r}")
        if len(data) > self.mtu:
            return refuse(f"{len(data)} bytes exceed the MTU ({self.mtu})")
        if self.modem is None or self.modem.kind is None:
            return refuse("nobody serves the modem now")
        dst = BROADCAST if to == UNET_BROADCAST else to
        h = header(protocol, datagram=not frame, control=frame and ftype == CONTROL)
        req = {"msgID": m.get("msgID"), "sender": m.get("sender"), "to": to, "protocol": protocol, "type": ftype,
               "reliable": m.get("reliability") is True}
        c.answer(fj.reply(m, "org.arl.fjage.Message", "AGREE", "phy"))
        tag = self.modem.send(dst, bytes([h]) + data)
        self._pending[tag] = (c, req, frame)
        while len(self._pending) > 100000:
            self._pending.pop(next(iter(self._pending)))
        self.counters["tx"] += 1
        return None

    def param_table(self, agent: str, index: int) -> dict[str, tuple[str, Any]]:
        """name -> (qualified name, value) of an agent's parameters (all read-only)."""
        with self._lock:
            loc = list(self.location) if self.location is not None else None
        if agent == "node" and index < 0:
            return {"address": (NODE_P + "address", self.address), "nodeName": (NODE_P + "nodeName", self.node_name),
                    "location": (NODE_P + "location", loc), "mobility": (NODE_P + "mobility", True)}
        if agent == "phy":
            rate = None if math.isnan(self.bitrate) else self.bitrate
            t = {"MTU": (DGRAM_P + "MTU", self.mtu), "dataRate": (CHAN_P + "dataRate", rate),
                 "maxFrameLength": (CHAN_P + "maxFrameLength", self.mtu + HEADER_BYTES)}
            if index < 0:
                t.update({"rxEnable": (PHY_P + "rxEnable", True)})
            return t if index in (-1, CONTROL, DATA) else {}
        return {}

    def parameters(self, agent: str, m: dict[str, Any]) -> bytes:
        """A ParameterRsp as fjåge's ParameterMessageBehavior makes it: unknown parameters are left out,
        a set of a read-only one answers its value and lists it read-only."""
        index = m.get("index", -1)
        index = index if _int(index) else -1
        table = self.param_table(agent, index)
        asked: list[str] = []
        if isinstance(m.get("param"), str):
            asked.append(m["param"])
        for r in m.get("requests") or []:
            if isinstance(r, dict) and isinstance(r.get("param"), str):
                asked.append(r["param"])
        if not asked:
            asked = [*table, "title", "description", "type"]
        values: dict[str, Any] = {}
        for p in asked:
            short = p.rsplit(".", 1)[-1]
            if short in table:
                values[table[short][0]] = table[short][1]
            elif short == "title":
                values["title"] = TITLES[agent]
            elif short == "description":
                values["description"] = f"{agent} of modem {self.id} (uwsimnet-zenoh)"
            elif short == "type":
                values["type"] = TYPES[agent]
        out: dict[str, Any] = {"index": index}
        readonly = list(values)
        if values:
            first = next(iter(values))
            value = values.pop(first)
            if values:
                out["values"] = values
            out.update(param=first, value=value)
        out["readonly"] = readonly              # last, as fjåge's ParameterRsp has it (see fj.reply)
        return fj.reply(m, "org.arl.fjage.param.ParameterRsp", "INFORM", agent, **out)


class _Client(ServerClient):
    def __init__(self, gw: UnetGateway) -> None:
        super().__init__(gw.clients)
        self.gw = gw
        self.reader = fj.LineReader()
        self.wants: set[str] | None = None
        self.peer = "?"
        self.gone = False
        self._held: deque[tuple[float, bytes]] = deque()
        self._quiet_until = 0.0         # loop time before which nothing may follow the last answer
        self._watch: tuple[float, int] | None = None     # (since, bytes taken then) while bytes wait
        self._written = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if self.accept(transport, self.gw.closing):
            peer = transport.get_extra_info("peername")
            self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
            self.gw.counters["connections"] += 1
            self.write(fj.ALIVE)

    def data_received(self, data: bytes) -> None:
        try:
            objs = self.reader.feed(data)
        except fj.ProtocolError as e:
            self.gw.counters["bad_line"] += 1
            log.warning("%s: client %s sent %s; closed", self.gw.id, self.peer, e)
            self.close()
            return
        for o in objs:
            if isinstance(o, fj.ProtocolError):
                self.gw.counters["bad_json"] += 1
                log.warning("%s: client %s sent a line that is %s; skipped", self.gw.id, self.peer, o)
                continue
            try:
                self.gw.action(self, o)
            except Exception as e:  # noqa: BLE001 - one client's odd message never stops the node
                self.gw.counters["bad_message"] += 1
                log.warning("%s: client %s: %s: %s; skipped", self.gw.id, self.peer, type(e).__name__, e)

    def refuse_line(self, why: str) -> None:
        self.gw.counters["bad_message"] += 1
        log.warning("%s: client %s sent %s; skipped", self.gw.id, self.peer, why)

    def answer(self, data: bytes) -> None:
        """A reply to a request: after REPLY_DELAY_S, and a notification after it REPLY_DELAY_S later still."""
        self.write(data, REPLY_DELAY_S, answer=True)

    def write(self, data: bytes, delay: float = 0.0, answer: bool = False) -> None:
        """In order: what comes after a delayed answer waits for it, and leaves REPLY_DELAY_S after it
        (fjagepy reads an AGREE, then registers the waiter of the notification that follows: a
        TxFrameNtf of a short frame written right behind the AGREE could fall between its queue check
        and that registration, and a BLOCKING send would wait for ever)."""
        loop = self.gw._io.loop
        now = loop.time()
        t = now + delay if answer else max(now + delay, self._quiet_until)
        if answer:
            self._quiet_until = max(self._quiet_until, t + REPLY_DELAY_S)
        if t <= now and not self._held:
            self._put(data)
            return
        if self._held:
            t = max(t, self._held[-1][0])
        self._held.append((t, data))
        if len(self._held) == 1:
            loop.call_at(t, self._flush)

    def _flush(self) -> None:
        loop = self.gw._io.loop
        now = loop.time()
        while self._held and self._held[0][0] <= now:
            self._put(self._held.popleft()[1])
        if self._held:
            loop.call_at(self._held[0][0], self._flush)

    def _put(self, data: bytes) -> None:
        t = self.transport
        if t is None or t.is_closing():
            return
        waiting = self.waiting()
        if waiting > MAX_BACKLOG:
            if not self.gone:
                self.gone = True
                self.gw.counters["slow_client"] += 1
                log.warning("%s: client %s does not read (%d bytes waiting); closed", self.gw.id, self.peer,
                            waiting)
                t.abort()
            return
        t.write(data)
        self._written += len(data)
        if self._watch is None:
            self._watch = (self.gw._io.loop.time(), self._written - self.waiting())
            self.gw._io.loop.call_later(1.0, self._check)

    def _check(self) -> None:
        """Once a second while bytes wait for the client: closed when it has taken none for STALL_S."""
        t, w = self.transport, self.waiting()
        if self._watch is None or t is None or t.is_closing() or w == 0:
            self._watch = None
            return
        now, taken = self.gw._io.loop.time(), self._written - w
        since, before = self._watch
        if taken > before:                               # it reads: start again from here
            since = now
        elif now - since >= STALL_S and not self.gone:
            self.gone = True
            self.gw.counters["slow_client"] += 1
            log.warning("%s: client %s does not read (%d bytes waiting, none taken for %.0f s); closed", self.gw.id,
                        self.peer, w, now - since)
            t.abort()
            self._watch = None
            return
        self._watch = (since, taken)
        self.gw._io.loop.call_later(1.0, self._check)


def _int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _us(t: float | None) -> int | None:
    """Simulation seconds as UnetStack's microsecond times."""
    return int(round(t * 1e6)) if t is not None and math.isfinite(t) else None
