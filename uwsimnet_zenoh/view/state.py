"""What the page shows, as plain data (sans-IO): the document of a replay or of a live world, and the
updates that keep a live one current.

The page (static/view.js) gets one document, then (live) a stream of updates:

    document  {mode, title, t0, t1, positions, vehicles, devices, poses, frames, events, clock, control}
    updates   {"type": "pose", "vehicle", "s": [t, x, y, z]}       a pose sample
              {"type": "event", "e": [t, dev, ev, reason, fifo, enq, tx, rx, drop, src, seq, kind]}
              {"type": "frame", "f": AirFrame.to_dict()}           created at tx, sent again per outcome
              {"type": "clock", "clock": {t, paused, speed, epoch}}
              {"type": "devices", "devices": {...}, "vehicles": {...}}
              {"type": "kind", "dev", "kind"}                      sim | real | null (nobody serves it)
              {"type": "control", "control": bool}                 whether pause/resume may be asked
              {"type": "link", "dev", "rx", "s": [t, per, level]}  a live link sample (LiveLinks)

`events` carry each device's cumulative counters after the event and its FIFO occupancy (bytes, carried
forward), so the page finds the state of a device at any time by a binary search, and a bounded live
history still shows true totals.  Each device has `per`, its PER-vs-distance curve [[m, PER], ...] (a
model whose loss is a function of range), or `links`, {receiver: [[t, PER, level dB], ...]} (a geometry
model such as Bellhop, asked along the scripted paths), or neither (no scene).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..analysis import TraceError
from ..analysis.airframes import AirFrame, AirTracker
from ..engine.network import Network
from ..scene.model import Scene
from .links import DEFAULT_LINK_SIZE, LiveLinks, geometry_links

PER_POINTS = 48
"""Samples of each transmitter's PER-vs-distance curve (the page interpolates linearly)."""
LIVE_FRAMES = 4000
LIVE_EVENTS = 20000
LIVE_POSES = 3000
"""Live history kept per kind (frames, events, pose samples per vehicle): older entries are forgotten."""
MAX_VEHICLES = 1000
"""Live vehicles kept: pose samples naming more (a forged flood of names) are refused and counted."""
CLOCK_FROM_TRACE_S = 0.05
"""Without clock samples, a trace record this much later than the time shown moves it."""


def _f(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def scene_parts(scene: Scene, link_size: int | None = None) -> dict[str, Any]:
    """Vehicles, devices (with PER curves) and scripted poses of a scene.

    Poses of scripted vehicles are their waypoints (piecewise linear, held outside: the page's linear
    interpolation is exact); static vehicles have one sample; `zenoh` vehicles none."""
    size = link_size or DEFAULT_LINK_SIZE
    vehicles: dict[str, Any] = {}
    poses: dict[str, list[list[float]]] = {}
    pts: list[tuple[float, float, float]] = []
    for v in scene.vehicles:
        if v.pose_source == "zenoh":
            vehicles[v.name] = {"source": "zenoh"}
            poses[v.name] = []
        elif v.trajectory:
            vehicles[v.name] = {"source": "trajectory"}
            poses[v.name] = [[w.t, w.x, w.y, w.z] for w in v.trajectory]
        else:
            vehicles[v.name] = {"source": "static"}
            poses[v.name] = [[0.0, *map(float, v.position)]]
        pts += [tuple(s[1:]) for s in poses[v.name]]
    arr = np.asarray(pts or [(0.0, 0.0, 0.0)], dtype=float)
    span = float(np.linalg.norm(arr.max(axis=0) - arr.min(axis=0))) * 1.5 + 10.0
    net = Network(scene, flows=False)
    devices: dict[str, Any] = {}
    for v, d in scene.devices():
        m = net.modems[d.dccomms_id]
        links = None
        if getattr(m.error, "by_distance", True):
            top = min(d.max_distance, span)
            ds = np.linspace(max(d.min_distance, 0.0), max(top, d.min_distance + 1e-6), PER_POINTS)
            per = np.asarray(m.error.per(ds, size + d.header_bytes), dtype=float).reshape(-1)
            curve = [[round(float(a), 3), round(float(b), 6)] for a, b in zip(ds, per, strict=True)]
        else:                   # the loss depends on where both ends are (depths, bathymetry): no curve of range
            curve = None
            links = geometry_links(scene, net, v, d, m.error, size + d.header_bytes, poses)
        devices[d.dccomms_id] = {
            "vehicle": v.name, "address": d.address, "tx_channel": d.tx_channel, "rx_channel": d.rx_channel,
            "bitrate": m.bitrate, "fifo_capacity": d.tx_fifo_bytes, "mac": d.mac.name, "kind": "sim",
            "min_distance": d.min_distance, "max_distance": _f(d.max_distance),
            "per": curve, "links": links, "link_size": size + d.header_bytes}
    return {"vehicles": vehicles, "devices": devices, "poses": poses, "positions": True}


def meta_parts(meta: dict[str, Any]) -> dict[str, Any]:
    """Vehicles and devices from a trace's meta line alone: no positions, no PER curves."""
    devices: dict[str, Any] = {}
    vehicles: dict[str, Any] = {}
    for dev, d in (meta.get("devices") or {}).items():
        if not isinstance(d, dict):
            continue
        for k in ("address", "tx_channel", "rx_channel"):          # #41: a string here was script in a page
            if d.get(k) is not None and (not isinstance(d[k], int) or isinstance(d[k], bool)):
                raise TraceError(f"meta line: device {str(dev)[:40]!r}: {k} {str(d[k])[:40]!r} is not an integer")
        veh = str(d.get("vehicle") or dev)
        vehicles.setdefault(veh, {"source": "unknown"})
        devices[dev] = {"vehicle": veh, "address": d.get("address"), "tx_channel": d.get("tx_channel"),
                        "rx_channel": d.get("rx_channel"), "bitrate": d.get("bitrate"), "mac": d.get("mac"),
                        "fifo_capacity": None, "kind": "sim", "per": None}
    return {"vehicles": vehicles, "devices": devices, "poses": {v: [] for v in vehicles}, "positions": False}


def typical_size(meta: dict[str, Any]) -> int | None:
    """Payload bytes of the scene's flows (the most common), for the link colours."""
    sizes = [f.get("size") for f in (meta.get("flows") or {}).values() if isinstance(f, dict)]
    sizes = [s for s in sizes if isinstance(s, int) and s >= 0]
    return max(set(sizes), key=sizes.count) if sizes else None


class Counters:
    """Cumulative per-device counters and FIFO occupancy, turned into the document's event rows."""

    def __init__(self) -> None:
        self._c: dict[str, list[int]] = {}
        self._fifo: dict[str, int] = {}

    def row(self, rec: dict[str, Any]) -> list[Any]:
        dev = rec["dev"]
        c = self._c.setdefault(dev, [0, 0, 0, 0])
        c[("enq", "tx", "rx", "drop").index(rec["ev"])] += 1
        if isinstance(rec.get("fifo"), int):
            self._fifo[dev] = rec["fifo"]
        return [rec["t"], dev, rec["ev"], rec.get("reason"), self._fifo.get(dev), *c, rec.get("src"), rec.get("seq"),
                rec.get("kind") or "data"]


def replay_document(meta: dict[str, Any], events: Iterable[dict[str, Any]], scene: Scene | None = None,
                    title: str = "") -> dict[str, Any]:
    """The whole document of a trace (TraceError from the events iterator propagates)."""
    parts = scene_parts(scene, typical_size(meta)) if scene is not None else meta_parts(meta)
    tracker = AirTracker()
    counters = Counters()
    rows: list[list[Any]] = []
    t_last = 0.0
    for rec in events:
        ev = rec.get("ev")
        if ev not in ("enq", "tx", "rx", "drop"):
            continue
        tracker.add(rec)
        rows.append(counters.row(rec))
        t_last = max(t_last, float(rec["t"]))
        if rec["dev"] not in parts["devices"]:          # a device the meta did not list (added at runtime)
            parts["devices"][rec["dev"]] = {"vehicle": None, "address": None, "tx_channel": rec["ch"],
                                            "rx_channel": rec["ch"], "fifo_capacity": None, "kind": "sim",
                                            "per": None}
    duration = meta.get("duration")
    t1 = max(t_last, float(duration) if isinstance(duration, int | float) and math.isfinite(duration) else 0.0)
    return {"mode": "replay", "title": title or str(meta.get("scene") or "trace"), "t0": 0.0, "t1": t1,
            **parts, "frames": [f.to_dict() for f in tracker.frames], "events": rows,
            "clock": {"t": 0.0, "paused": True, "speed": 1.0}, "control": False}


class LiveState:
    """The state of a live world, fed from Zenoh callbacks (any thread) and read by the web server.

    Every change is appended, numbered, to a bounded log of updates; a consumer that fell further behind
    than the log reaches takes a fresh `snapshot()` instead (a slow browser costs memory of one log, never
    a wait in the feeding thread)."""

    def __init__(self, title: str, parts: dict[str, Any] | None = None, log_size: int = 10000,
                 links: LiveLinks | None = None) -> None:
        self.lock = threading.Lock()
        self.links = links if links else None
        """The live links of geometry models with a Zenoh-posed end (`update_links`), or None."""
        self._links_dirty = False
        self.title = title
        p = parts or {"vehicles": {}, "devices": {}, "poses": {}, "positions": True}
        self.vehicles: dict[str, Any] = p["vehicles"]
        self.devices: dict[str, Any] = p["devices"]
        self.scripted = {v for v, s in p["vehicles"].items() if s.get("source") in ("static", "trajectory")}
        self.poses: dict[str, deque[list[float]]] = {v: deque(maxlen=LIVE_POSES) for v in self.vehicles}
        self.frames: dict[int, AirFrame] = {}
        self.frame_order: deque[int] = deque()
        self.events: deque[list[Any]] = deque(maxlen=LIVE_EVENTS)
        self.clock: dict[str, Any] = {"t": 0.0, "paused": False, "speed": 1.0, "epoch": None}
        self.clock_seen = False
        self.control = False
        self.kinds: dict[str, str | None] = {}
        self.refused_vehicles = 0
        self._tracker = AirTracker(keep=False)
        self._counters = Counters()
        self.log: deque[tuple[int, dict[str, Any]]] = deque(maxlen=log_size)
        self.seq = 0
        self.listeners: list[Any] = []
        """Callables run (outside the lock) after every change: the server's wake-up."""

    # -- feeding (Zenoh threads) -----------------------------------------------------------------
    def _push(self, upd: dict[str, Any]) -> None:
        self.seq += 1
        self.log.append((self.seq, upd))

    def _devices_update(self) -> dict[str, Any]:
        """Every device without its link series (the page keeps those; `link` updates extend them)."""
        return {"type": "devices", "devices": {k: {a: b for a, b in v.items() if a != "links"}
                                               for k, v in self.devices.items()},
                "vehicles": {k: dict(v) for k, v in self.vehicles.items()}}

    def _notify(self) -> None:
        for fn in self.listeners:
            fn()

    def trace(self, rec: dict[str, Any]) -> None:
        if rec.get("ev") not in ("enq", "tx", "rx", "drop"):
            return
        with self.lock:
            if not self.clock_seen and rec["t"] > self.clock["t"] + CLOCK_FROM_TRACE_S:
                # no clock samples (a visitor may read traces only): time as the trace tells it
                self.clock = {"t": float(rec["t"]), "paused": False, "speed": 1.0, "epoch": None, "source": "trace"}
                self._push({"type": "clock", "clock": self.clock})
            row = self._counters.row(rec)
            self.events.append(row)
            self._push({"type": "event", "e": row})
            f = self._tracker.add(rec)
            if f is not None:
                if f.id not in self.frames:
                    self.frames[f.id] = f
                    self.frame_order.append(f.id)
                    while len(self.frame_order) > LIVE_FRAMES:
                        self.frames.pop(self.frame_order.popleft(), None)
                self._push({"type": "frame", "f": f.to_dict()})
            if rec["dev"] not in self.devices:
                self.devices[rec["dev"]] = {"vehicle": None, "address": None, "tx_channel": rec["ch"],
                                            "rx_channel": rec["ch"], "fifo_capacity": None, "per": None,
                                            "kind": self.kinds.get(rec["dev"], "sim")}
                self._push(self._devices_update())
        self._notify()

    def pose(self, vehicle: str, p: tuple[float, float, float], t: float | None) -> None:
        with self.lock:
            t = self.clock["t"] if t is None else t
            s = [float(t), float(p[0]), float(p[1]), float(p[2])]
            q = self.poses.get(vehicle)
            if q is None:
                if len(self.poses) >= MAX_VEHICLES:
                    self.refused_vehicles += 1      # a flood of pose names (#41): counted, never stored
                    return
                q = self.poses[vehicle] = deque(maxlen=LIVE_POSES)
                self.vehicles.setdefault(vehicle, {"source": "zenoh"})
                self._push(self._devices_update())
            if vehicle in self.scripted:        # the scene's own samples are exact: keep them, add live ones
                self.scripted.discard(vehicle)
                q.clear()
            if q and q[-1][0] > s[0]:
                return                          # out of order (e.g. two publishers): keep time increasing
            q.append(s)
            self._push({"type": "pose", "vehicle": vehicle, "s": s})
            if self.links is not None and vehicle in self.links.external:
                self._links_dirty = True
        self._notify()

    def set_clock(self, m: dict[str, Any]) -> None:
        with self.lock:
            t = m.get("t")
            if not isinstance(t, int | float) or not math.isfinite(t):
                return
            self.clock_seen = True
            self.clock = {"t": float(t), "paused": bool(m.get("paused")), "speed": float(m.get("speed") or 1.0),
                          "epoch": m.get("epoch") if isinstance(m.get("epoch"), int | float) else None}
            self._push({"type": "clock", "clock": self.clock})
        self._notify()

    def set_control(self, allowed: bool) -> None:
        """Whether the world's control API answers this client (pause/resume on the page)."""
        with self.lock:
            if allowed == self.control:
                return
            self.control = allowed
            self._push({"type": "control", "control": allowed})
        self._notify()

    def set_kind(self, dev: str, kind: str | None) -> None:
        with self.lock:
            self.kinds[dev] = kind
            if dev in self.devices:
                self.devices[dev]["kind"] = kind
            self._push({"type": "kind", "dev": dev, "kind": kind})
        self._notify()

    def merge_state(self, state: dict[str, Any]) -> None:
        """The reply of control `state` (or info replies shaped alike): modems and vehicles of the world."""
        changed = False
        with self.lock:
            for name, v in (state.get("vehicles") or {}).items():
                if isinstance(v, dict) and name not in self.vehicles:
                    self.vehicles[name] = {"source": v.get("source") or "unknown"}
                    self.poses.setdefault(name, deque(maxlen=LIVE_POSES))
                    changed = True
            for dev, m in (state.get("modems") or {}).items():
                if not isinstance(m, dict):
                    continue
                d = self.devices.setdefault(dev, {"per": None, "fifo_capacity": None})
                for k in ("vehicle", "address", "tx_channel", "rx_channel", "fifo_capacity", "max_distance", "mac",
                          "bitrate"):
                    if m.get(k) is not None and d.get(k) != m[k]:
                        d[k] = m[k]
                        changed = True
                kind = self.kinds.get(dev, m.get("kind"))
                if d.get("kind") != kind:
                    d["kind"] = kind
                    changed = True
            if changed:
                self._push(self._devices_update())
        if changed:
            self._notify()

    def update_links(self) -> int:
        """Ask the geometry models about the links with a Zenoh-posed end, if a pose came since the last
        time (called by the live source's thread, never a Zenoh callback); the number of link samples added."""
        if self.links is None:
            return 0
        with self.lock:
            if not self._links_dirty:
                return 0
            self._links_dirty = False
            t = float(self.clock["t"])
            latest = {v: (q[-1][1], q[-1][2], q[-1][3]) for v in self.links.external if (q := self.poses.get(v))}
        rows = self.links.compute(t, latest)
        n = 0
        with self.lock:
            for tx, rx, sample in rows:
                d = self.devices.get(tx)
                if d is None:
                    continue
                if not isinstance(d.get("links"), dict):
                    d["links"] = {}
                series = d["links"].setdefault(rx, [])
                if series and series[-1][0] >= sample[0]:
                    continue                            # the clock has not moved (paused): nothing new
                series.append(sample)
                if len(series) > LIVE_POSES:
                    del series[0]
                self._push({"type": "link", "dev": tx, "rx": rx, "s": sample})
                n += 1
        if n:
            self._notify()
        return n

    # -- reading (web server) --------------------------------------------------------------------
    def snapshot(self) -> tuple[int, dict[str, Any]]:
        """(the update number it includes, the document)."""
        with self.lock:
            doc = {"mode": "live", "title": self.title, "t0": 0.0, "t1": self.clock["t"],
                   "positions": True, "vehicles": dict(self.vehicles),
                   "devices": {k: {**v, "links": {r: list(x) for r, x in v["links"].items()}}
                               if isinstance(v.get("links"), dict) else dict(v) for k, v in self.devices.items()},
                   "poses": {v: list(q) for v, q in self.poses.items()},
                   "frames": [self.frames[i].to_dict() for i in self.frame_order if i in self.frames],
                   "events": list(self.events), "clock": dict(self.clock), "control": self.control}
            return self.seq, doc

    def since(self, seq: int) -> tuple[int, list[dict[str, Any]]] | None:
        """(the last update number, the updates after number `seq`), or None if some of them are no longer
        in the log (the consumer fell behind: it takes a snapshot)."""
        with self.lock:
            if seq >= self.seq:
                return self.seq, []
            if not self.log or self.log[0][0] > seq + 1:
                return None
            return self.seq, [u for n, u in self.log if n > seq]
