"""The broker's queries: `info` (a served modem's configuration and live state) and `control/<op>`
(bus/control.py), and the edge summary of the run (a part of bus/broker.Broker, which mixes it in).

A query waits in its lane, which takes its turn among the modems' tx lanes (kernel/realtime.py's inbox): a
flood of queries costs the other modems' frames one query per round, not the whole flood.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys, is_chunk

from .outbox import Lane, Outbox, Throttle

if TYPE_CHECKING:
    from ..engine.network import Network
    from ..kernel.realtime import RealtimeClock
    from .control import Control


class Queries:
    """`info` and `control` queries of a `Broker`, and its edge summary (the attributes are the broker's)."""

    net: Network
    clock: RealtimeClock
    keys: Keys
    control: Control
    endpoints: dict[str, Any]
    lanes: dict[str, Lane]
    outboxes: dict[str, Outbox]
    warn: Throttle
    _info_lane: Lane
    _control_lane: Lane
    real: set[str]                                  # (the broker's: modems a real driver serves)
    _pull_poses: Callable[[float], None]            # (bus/poses.py)

    def _on_info_query(self, query: zenoh.Query) -> None:
        self._queue_query(self._info_lane, query, self._answer_info, query)

    def _on_control_query(self, query: zenoh.Query) -> None:
        pl = query.payload
        raw = pl.to_bytes() if pl is not None and len(pl) <= wire.MAX_SMALL_MESSAGE else pl
        self._queue_query(self._control_lane, query, self._answer_control, query, raw)

    def _queue_query(self, lane: Lane, query: zenoh.Query, fn: Any, *args: Any) -> None:
        """(Zenoh thread) A query waits in its lane, which takes its turn among the modems' tx lanes: a
        flood of queries costs the other modems' frames one query per round, not the whole flood."""
        r = lane.offer((fn, args))
        if r:
            self.clock.call_soon(self._drain_queries, lane)
        elif r is None:
            with contextlib.suppress(Exception), query:
                query.reply_err(wire.pack({"ok": False, "error": f"busy: {lane.capacity} queries are waiting"}))
            self.warn(f"ingress:{lane.name}", "%s query refused: %d queries waiting for the engine", lane.name[1:],
                      len(lane))

    def _drain_queries(self, lane: Lane) -> None:
        """(engine) One query of `lane`, then back in line behind the modems."""
        got = lane.take()
        if got is None:
            return
        _, (fn, args) = got
        try:
            fn(*args)
        finally:
            if lane.more():
                self.clock.call_soon(self._drain_queries, lane)

    def info(self, dev: str) -> dict[str, Any]:
        """The `info` reply of a served modem: configuration, kind and live state."""
        m = self.endpoints[dev].modem
        net = self.net
        cfg = m.cfg
        self._pull_poses(net.sched.now)
        known = bool(net.poses.known[m.vehicle_index])
        pos = net.poses.points(net.sched.now)[m.vehicle_index] if known else None
        ep = self.endpoints[dev]
        counters = dict(m.counters)
        counters.update(ep.bad)
        return ep.info({
            "address": m.address, "vehicle": m.vehicle,
            "tx_channel": m.tx_channel.id, "rx_channel": m.rx_channel.id, "bitrate": m.bitrate,
            # the tx channel's delay law, the parameters phy.channel.Channel computes delays with
            "prop": {"min": m.tx_channel.min_prop_s, "per_m": m.tx_channel.prop_s_per_m},
            "rx_prop": {"min": m.rx_channel.min_prop_s, "per_m": m.rx_channel.prop_s_per_m},
            "header_bytes": m.header_bytes, "max_frame_bytes": cfg.max_frame_bytes,
            "tx_framing": cfg.tx_framing, "rx_framing": cfg.rx_framing or cfg.tx_framing,
            "fifo_capacity": m.fifo_cap, "fifo_bytes": m.fifo_bytes, "fifo_frames": len(m.fifo),
            "phy_busy": m.phy_busy, "mac": cfg.mac.name, "pose_known": known,
            "position": None if pos is None else [float(x) for x in pos],
            "counters": counters, "config": cfg.model_dump(mode="json", exclude={"line"}),
            "epoch": self.clock.wall_epoch(), "speed": self.clock.speed,
            # + the edge (docs/runtime.md): messages lost because their consumer did not keep up, and the
            # ingress delay (wall s from the tx put reaching the broker to the engine taking it)
        }, kind="sim", world=self.keys.world, t=net.sched.now, ingress=ep.lane.stats())

    def _answer_info(self, query: zenoh.Query) -> None:
        with query:
            ke = query.key_expr
            for dev in list(self.endpoints):
                if dev in self.real:
                    continue
                key = self.keys.info(dev)
                if ke.intersects(key):
                    query.reply(key, wire.pack(self.info(dev)))

    def _answer_control(self, query: zenoh.Query, raw: Any) -> None:
        with query:
            ke = query.key_expr
            op = str(ke).rsplit("/", 1)[-1]
            if not is_chunk(op) or not ke.intersects(self.keys.control(op)):
                op, reply = "?", {"ok": False, "error": "name one operation: control/<op>"}
            else:
                if raw is not None and not isinstance(raw, bytes):
                    reply = {"ok": False, "error": f"request larger than {wire.MAX_SMALL_MESSAGE} bytes"}
                else:
                    try:
                        reply = self.control.handle(op, wire.decode_request(raw))
                    except wire.CodecError as e:
                        reply = {"ok": False, "error": f"{e.reason}: {e.detail}"}
            if not reply.get("ok"):
                self.warn(f"control:{op}", "control/%s refused: %s", op, reply.get("error"))
            if op == "?":
                query.reply_err(wire.pack(reply))
            else:
                query.reply(self.keys.control(op), wire.pack(reply))

    def edge_summary(self) -> dict[str, Any]:
        """Per modem: messages lost at the edge (outbox full, by kind; ingress lane full) and the ingress
        delay (count, mean, max wall s); plus the trace and misc outboxes.  For the run summary."""
        out: dict[str, Any] = {}
        for dev, lane in self.lanes.items():
            ob = self.outboxes.get(dev)
            out[dev] = {"lost": dict(ob.dropped) if ob is not None else {}, "refused": lane.refused,
                        "stalled": dict(ob.stalled) if ob is not None else {},
                        "stalled_max": ob.stalled_max if ob is not None else 0.0,
                        "lost_rx": list(ob.lost_ids) if ob is not None else [],
                        "stalled_rx": list(ob.stalled_ids) if ob is not None else [],
                        "ingress_n": lane.n, "ingress_mean": lane.delay_sum / lane.n if lane.n else 0.0,
                        "ingress_max": lane.delay_max}
        for name in ("*trace", "*misc"):
            ob = self.outboxes.get(name)
            if ob is not None and (ob.dropped or ob.stalled):
                out[name] = {"lost": dict(ob.dropped), "stalled": dict(ob.stalled), "stalled_max": ob.stalled_max}
        return out
