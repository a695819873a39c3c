"""DcMac: the TWINBOT authors' own master/slave MAC (dccomms_examples `src/DcMac.cpp` at 3cfb74d, the version
the 2019 TWINBOT runs built; later moved unchanged in logic to dcentelles/umci-mac).  In the original it ran in
the application process above a simulator with no MAC; here it runs in the modem, so the original's
`netsim_twinbot_dcmac*` scenes and `mac_twinbot.sh dcmac` run without their apps.  docs/mac.md cites every
rule (file:line); in short, one cycle of the master (address 0 unless `master` says otherwise):

    SYNC (6 B, broadcast, carries the ACK bits of the slaves' data the master got last cycle)
    wait the intrinsic delay in whole ms (the SYNC's airtime is lost to an integer division)
    maxNodes RTS slots of `slot` each: slave k sends its RTS (7 B: data size, ACK bits) at (k-1)*slot
    CTS (7 B) to each requester, fewest bytes granted first; wait for its DATA or slot + its tx time
    the master's own DATA: the head of each destination's queue, back to back; 10 ms; next SYNC

    slot = floor(tx time of 7 B + intrinsic delay + maxDistance / speed + 45 ms), in ms

A DATA to the master is acknowledged in the next SYNC, one to a slave in that slave's next RTS; without the
acknowledgement it is sent again in the next cycle, for ever (DcMac has no retry limit).  Differences, all
documented: a frame delivered twice (a lost acknowledgement) reaches the application once here; a frame to
255 is refused (`broadcast`: DcMac has no broadcast address); the RTS announces the DATA's size on air.
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING, Any

from ..kernel.frame import BROADCAST, Frame
from .aloha import Dedup, max_distance, number
from .base import Mac, MacContext
from .registry import register

if TYPE_CHECKING:
    from ..kernel.scheduler import Event

SYNC_BYTES = 6
"""DcMacPacket sync: 55 | addresses | flags | master ACK mask | CRC16 (DcMac.h:64-67, _GetTypeSize)."""
RTS_CTS_BYTES = 7
"""DcMacPacket rts/cts: 55 | addresses | flags | 2-byte size field | CRC16."""
SLOT_ERROR_MS = 45
"""DcMac::UpdateSlotDurFromEstimation's margin, ms (DcMac.cpp:456)."""
MASTER_PAUSE = 0.010
"""The master's sleep after its own data, before the next SYNC (DcMac.cpp:833)."""
SLAVE_ACK_BITS = 5
"""An RTS's ACK mask is the size field's top five bits (SetSlaveAckMask: mask << 3): addresses 0..4."""


def _ms(seconds: float) -> float:
    """A duration as DcMac keeps it: whole milliseconds (uint32 `_rtsCtsSlotDur`, `minEnd2End`)."""
    return math.floor(seconds * 1000 + 1e-9) / 1000


def rts_size_field(size: int) -> int:
    """What an RTS/CTS carries of a size: half of it rounded up, read back doubled (DcMac.cpp:237-247)."""
    return 2 * math.ceil(size / 2)


@register("dcmac", "umci-mac")
class DcMac(Mac):
    overhear = True                         # a slave's ACK to another slave is in an RTS addressed to the master

    def __init__(self, ctx: MacContext, params: dict[str, str]) -> None:
        super().__init__(ctx, params)
        self.master = number(self, "master", 1 if ctx.address == 0 else 0, minimum=0, integer=True) == 1
        self.max_nodes = number(self, "maxNodes", 4, minimum=1, integer=True)
        if not self.master and ctx.address < 1:
            raise ValueError("macProtocol dcmac: a slave's address is 1 or more (its RTS slot is address - 1)")
        self.max_distance = max_distance(self)
        default = _ms(ctx.tx_time(RTS_CTS_BYTES) + ctx.tx_delay + ctx.max_prop_delay(self.max_distance)
                      + SLOT_ERROR_MS / 1000)
        self.slot = number(self, "slotTime", default, minimum=1e-3)
        self._out: deque[Frame] = deque()   # frames waiting for our transmitter
        self._dedup = Dedup()
        self._closed = False
        # master
        self._queues: dict[int, deque[Frame]] = {}      # per destination; the head is sent until acked
        self._req: dict[int, tuple[int, int]] = {}       # slave -> (announced size, its data's dst)
        self._granted: dict[int, int] = {}               # slave -> bytes granted (ctsBytes)
        self._ack_mask: set[int] = set()                 # slaves whose data to us arrived this cycle
        self._grantee: int | None = None
        self._wait: Event | None = None
        # slave
        self.cur: Frame | None = None
        self._waiting_ack = False
        self._acks_to_send: set[int] = set()
        self._cycle: list[Event] = []
        if self.master:
            ctx.timer(0.0, self._sync)

    # -- the interface ------------------------------------------------------------------------
    def ready(self) -> bool:
        return False                        # frames wait in the FIFO for their turn in the cycle

    def on_queue(self) -> None:
        ctx = self.ctx
        while self._closed and (f := ctx.fifo_pop()) is not None:
            ctx.drop(f, "removed")

    def on_tx_done(self, frame: Frame) -> None:
        if frame.kind == "data":
            self.ctx.status(frame, "transmitted")
        if self._out and not self.ctx.phy_busy:
            self.ctx.transmit(self._out.popleft())

    def on_rx(self, frame: Frame, rx: Any) -> None:
        self._heard(frame, rx, mine=True)

    def on_overhear(self, frame: Frame, rx: Any) -> None:
        self._heard(frame, rx, mine=False)

    def close(self) -> None:
        self._closed = True
        for ev in (*self._cycle, self._wait):
            if ev is not None:
                ev.cancel()
        pending = [*self._out, *(f for q in self._queues.values() for f in q)]
        if self.cur is not None:
            pending.append(self.cur)
        self._out.clear()
        self._queues.clear()
        self.cur = None
        for f in pending:
            if f.kind == "data":
                self.ctx.drop(f, "removed")
        self.on_queue()

    # -- common -------------------------------------------------------------------------------
    def _send(self, frame: Frame) -> None:
        """Hand a frame down; the original writes to its stream whether or not the device is sending."""
        if self._closed:
            return
        if self.ctx.phy_busy or self._out:
            self._out.append(frame)
        else:
            self.ctx.transmit(frame)

    def _ctrl(self, kind: str, to: int, about: Frame | None = None, **info: object) -> Frame:
        """A control frame; an RTS for our data is counted for its flow (efficiency), SYNC and CTS for none."""
        size = SYNC_BYTES if kind == "SYNC" else RTS_CTS_BYTES
        return self.ctx.ctrl_frame(to, size, {"type": kind, **info}, about=about)

    def _take(self) -> Frame | None:
        """The FIFO head; a broadcast frame is refused (DcMac has no broadcast address)."""
        ctx = self.ctx
        while (f := ctx.fifo_pop()) is not None:
            if f.dst == BROADCAST or f.broadcast:
                ctx.drop(f, "broadcast")
                continue
            return f
        return None

    def _heard(self, frame: Frame, rx: Any, mine: bool) -> None:
        ctx = self.ctx
        if frame.kind == "data":
            if self.master and frame.src == self._grantee:
                self._granted_done()                             # the wait ends on any data (DcMac.cpp:808-822)
            if frame.dst != ctx.address:
                return
            if self.master:
                self._ack_mask.add(frame.src)                    # DcMac.cpp:814-816: ACK bit in the next SYNC
            else:
                self._acks_to_send.add(frame.src)                # DcMac.cpp:981-984: ACK bit in our next RTS
            if self._dedup.first(frame):
                ctx.deliver(frame, rx)
            return
        if mine:
            ctx.trace_rx(frame, rx)
        info = frame.info or {}
        kind = info.get("type")
        if self.master:
            if kind == "RTS":
                self._master_rts(frame, info)
        elif kind == "SYNC":
            self._slave_sync(info)
        elif kind == "CTS" and frame.dst == ctx.address:
            self._slave_cts()
        elif kind == "RTS" and ctx.address in info.get("acks", ()):
            self._slave_acked(frame.src)

    # -- master -------------------------------------------------------------------------------
    def _sync(self) -> None:
        """A cycle starts (DcMac.cpp:717-743): the SYNC with last cycle's ACK bits, then the RTS slots."""
        if self._closed:
            return
        ctx = self.ctx
        self._cycle = []                                            # last cycle's sends have fired
        self._send(self._ctrl("SYNC", BROADCAST, acks=sorted(self._ack_mask)))
        self._req.clear()
        # minEnd2End (:740-743): (size * 8) / _devBitRate is an integer division (uint32), so whole seconds of
        # airtime only (none above 48 bps), plus the intrinsic delay, in whole ms
        wait = _ms(math.floor(ctx.tx_time(SYNC_BYTES) + 1e-12) + ctx.tx_delay)
        self._wait = ctx.timer(wait + self.max_nodes * self.slot, self._grant)

    def _master_rts(self, rts: Frame, info: dict) -> None:
        if self.ctx.address in info.get("acks", ()):
            q = self._queues.get(rts.src)                          # DcMac.cpp:877-885: our data was acked
            if q:
                f = q.popleft()
                self.ctx.status(f, "acked")
        size = int(info.get("size", 0))
        if size > 0:
            self._req[rts.src] = (size, int(info.get("dst", 0)))    # DcMac.cpp:889-899

    def _grant(self) -> None:
        """CTS to the requester granted the fewest bytes so far, one at a time (DcMac.cpp:774-826)."""
        self._wait = None
        if self._closed:
            return
        if self._grantee is None:
            self._ack_mask = set()                                  # :775, after the SYNC carried it
        if not self._req:
            self._grantee = None
            self._master_data()
            return
        slave = min(self._req, key=lambda s: (self._granted.get(s, 0), s))
        size, _dst = self._req.pop(slave)
        self._granted[slave] = self._granted.get(slave, 0) + size
        self._grantee = slave
        self._send(self._ctrl("CTS", slave, size=size))
        ctx = self.ctx
        wait = math.ceil((self.slot + ctx.tx_time(size) + ctx.tx_delay) * 1000 - 1e-6) / 1000   # :805-807
        self._wait = ctx.timer(wait, self._grant)

    def _granted_done(self) -> None:
        """The grantee's DATA arrived: the next CTS at once (the wait ends on `datareceived`)."""
        if self._wait is not None:
            self._wait.cancel()
        self._wait = self.ctx.timer(0.0, self._grant)

    def _master_data(self) -> None:
        """PrepareDataAndSend (DcMac.cpp:664-703): the FIFO into per-destination queues, then the head of each,
        `round(tx time)` ms apart; then 10 ms and the next SYNC."""
        while (f := self._take()) is not None:
            self._queues.setdefault(f.dst, deque()).append(f)
        ctx = self.ctx
        t = 0.0
        for dst in sorted(self._queues):
            q = self._queues[dst]
            if q:
                self._cycle.append(ctx.timer(t, self._send, q[0]))
                t += round((ctx.tx_time(q[0].size) + ctx.tx_delay) * 1000) / 1000
        self._wait = ctx.timer(t + MASTER_PAUSE, self._sync)

    # -- slave --------------------------------------------------------------------------------
    def _slave_sync(self, info: dict) -> None:
        """SlaveRunTx's iteration (DcMac.cpp:474-627), from the SYNC."""
        ctx = self.ctx
        for ev in self._cycle:
            ev.cancel()
        self._cycle = []
        cur = self.cur
        if cur is not None and cur.dst == 0 and self._waiting_ack:
            self._waiting_ack = False                              # :482-490: the SYNC's ACK bit, or again
            if ctx.address in info.get("acks", ()):
                self._acked()
        self._cycle.append(ctx.timer((ctx.address - 1) * self.slot, self._slave_slot))
        cur = self.cur
        if cur is not None and self._waiting_ack and cur.dst > ctx.address:
            self._cycle.append(ctx.timer(self.max_nodes * self.slot, self._ack_lost))   # :580-596

    def _slave_slot(self) -> None:
        """Our RTS slot: the data's RTS (unless an ACK is awaited) with the ACK bits of what we got (:497-570)."""
        ctx = self.ctx
        cur = self.cur
        if cur is not None and self._waiting_ack and 0 < cur.dst < ctx.address:
            self._waiting_ack = False                              # :497-512: no ACK before our slot
        acks = sorted(a for a in self._acks_to_send if a < SLAVE_ACK_BITS)
        self._acks_to_send.clear()
        if self.cur is None:
            self.cur = self._take()
        size = rts_size_field(self.cur.size) if self.cur is not None and not self._waiting_ack else 0
        if size or acks:
            dst = self.cur.dst if size and self.cur is not None else 0
            self._send(self._ctrl("RTS", dst, self.cur if size else None, size=size, dst=dst, acks=acks))

    def _ack_lost(self) -> None:
        self._waiting_ack = False                                  # sent again from the next cycle on

    def _slave_cts(self) -> None:
        cur = self.cur
        if cur is None or self._waiting_ack:
            return
        self._waiting_ack = True                                    # :615-626
        self._send(cur)

    def _slave_acked(self, by: int) -> None:
        cur = self.cur
        if cur is not None and cur.dst == by and self._waiting_ack:
            self._waiting_ack = False
            self._acked()

    def _acked(self) -> None:
        cur, self.cur = self.cur, None
        if cur is not None:
            self.ctx.status(cur, "acked")
