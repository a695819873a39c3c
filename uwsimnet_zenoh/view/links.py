"""What a channel model says of each link, for the view's colours (docs/view.md, "Links"), sans-IO.

A model whose loss is a function of range gets a PER-vs-distance curve (state.scene_parts).  A geometry model
(Bellhop: depths, the sound-speed profile, the bottom; `ocean` with a Doppler tolerance: velocities) is asked
as the engine asks it, from the run's pose table: along the scripted paths before the run (`geometry_links`),
and live at the latest poses of the vehicles in the loop (`LiveLinks`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..engine.network import Network
from ..kernel.frame import Frame
from ..phy.models import Query
from ..scene.model import Scene

DEFAULT_LINK_SIZE = 64
"""Bytes on air of the frame the link colours are computed for when nothing better is known."""
LINK_STEPS = 20
"""Geometry models: each interval between two waypoint times is cut into this many steps, at whose ends the
model is asked for a link's PER (the page interpolates linearly in time)."""
LINK_SAMPLES = 400
"""At most this many samples per link (evenly spread over the run when the waypoints ask for more)."""


def _f(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def geometry_links(scene: Scene, net: Network, veh: Any, dev: Any, model: Any, size: int,
                   poses: dict[str, list[list[float]]]) -> dict[str, list[list[Any]]]:
    """What `dev`'s channel model says of its frames at each receiver over the run: {receiver id: [[t, per,
    level dB or None], ...]} (per None: out of range), asked as the engine asks it, from the run's pose table
    (scripted positions and velocities at t), one query per time for every receiver at once.  For models whose
    loss is not a function of range alone (Bellhop's shadow zones, bathymetry, a Doppler tolerance).
    Vehicles whose pose comes from Zenoh are left out (no positions before the run)."""
    if veh.pose_source == "zenoh":
        return {}
    rxs = [(v, r) for v, r in scene.devices() if r.dccomms_id != dev.dccomms_id and v.name != veh.name
           and r.rx_channel == dev.tx_channel and v.pose_source != "zenoh"]
    if not rxs:
        return {}
    end = scene.end_time()
    names = [veh.name, *dict.fromkeys(v.name for v, _ in rxs)]
    marks = sorted({0.0, end, *(s[0] for n in names for s in poses[n] if 0.0 <= s[0] <= end)})
    ts = sorted({float(a + (b - a) * k / LINK_STEPS) for a, b in zip(marks, marks[1:], strict=False)
                 for k in range(LINK_STEPS + 1)} or {0.0})
    if len(ts) > LINK_SAMPLES:
        ts = [float(t) for t in np.linspace(0.0, end, LINK_SAMPLES)]
    table, index = net.poses, net.poses.index
    frame = Frame(0, 0, 0, int(size), int(size))
    out: dict[str, list[list[Any]]] = {r.dccomms_id: [] for _, r in rxs}
    for t in ts:
        at = table.points(t)
        me = at[index[veh.name]]
        dist = [math.dist(me, at[index[v.name]]) for v, _ in rxs]
        live = [k for k, d in enumerate(dist) if dev.min_distance <= d <= dev.max_distance]
        try:
            ans = model.answer(Query(t, frame, [dist[k] for k in live], list(range(len(live))), table,
                                     index[veh.name], [index[rxs[k][0].name] for k in live])) if live else None
        except Exception:  # noqa: BLE001 - a plug-in that cannot answer here: its links stay unknown (grey)
            return {}
        got = {k: j for j, k in enumerate(live)}
        for k, (_, r) in enumerate(rxs):
            if k not in got or ans is None:
                out[r.dccomms_id].append([round(t, 6), None, None])      # out of range: no link to colour
                continue
            lv = None if ans.level_db is None else _f(ans.level_db[got[k]])
            out[r.dccomms_id].append([round(t, 6), round(float(ans.per[got[k]]), 6),
                                      None if lv is None else round(lv, 2)])
    return out


class LiveLinks:
    """Live (HIL): the modelled PER of the links of a geometry model that have an end whose pose comes from
    Zenoh, asked of the scene's models at the latest poses received (velocity zero: a pose sample has none
    here), so the page colours them as it colours the scripted ones (`geometry_links`).  Sans-IO: the live
    source calls `compute` from a thread of its own."""

    def __init__(self, scene: Scene, link_size: int | None = None) -> None:
        size = link_size or DEFAULT_LINK_SIZE
        self.net = Network(scene, flows=False)
        self.external = {v.name for v in scene.vehicles if v.pose_source == "zenoh"}
        self.pairs: list[tuple[str, str, Any, Any, list[tuple[str, str]]]] = []
        """(transmitter id, its vehicle, its model, a frame of the link size, [(receiver id, its vehicle)])."""
        for v, d in scene.devices():
            model = self.net.modems[d.dccomms_id].error
            if getattr(model, "by_distance", True):
                continue
            rxs = [(r.dccomms_id, rv.name) for rv, r in scene.devices() if r.dccomms_id != d.dccomms_id
                   and rv.name != v.name and r.rx_channel == d.tx_channel
                   and (v.name in self.external or rv.name in self.external)]
            if rxs:
                n = size + d.header_bytes
                self.pairs.append((d.dccomms_id, v.name, model, Frame(0, 0, 0, n, n), rxs))
        self._range = {d.dccomms_id: (d.min_distance, d.max_distance) for _, d in scene.devices()}

    def __bool__(self) -> bool:
        return bool(self.pairs)

    def compute(self, t: float, latest: dict[str, tuple[float, float, float]]) -> list[tuple[str, str, list[Any]]]:
        """[(transmitter, receiver, [t, PER or None, level dB or None])] for every link whose ends are known."""
        table, index = self.net.poses, self.net.poses.index
        for name, p in latest.items():
            table.update(name, t, p)
        at = table.points(t)
        out: list[tuple[str, str, list[Any]]] = []
        for tx, veh, model, frame, rxs in self.pairs:
            if veh in self.external and veh not in latest:
                continue
            known = [(r, rv) for r, rv in rxs if rv not in self.external or rv in latest]
            lo, hi = self._range[tx]
            dist = [math.dist(at[index[veh]], at[index[rv]]) for _, rv in known]
            live = [k for k, d in enumerate(dist) if lo <= d <= hi]
            try:
                ans = model.answer(Query(t, frame, [dist[k] for k in live], list(range(len(live))), table,
                                         index[veh], [index[known[k][1]] for k in live])) if live else None
            except Exception:  # noqa: BLE001 - a plug-in that cannot answer: these links stay unknown
                continue
            got = {k: j for j, k in enumerate(live)}
            for k, (r, _) in enumerate(known):
                if ans is None or k not in got:
                    out.append((tx, r, [round(t, 6), None, None]))
                    continue
                lv = None if ans.level_db is None else _f(ans.level_db[got[k]])
                per = round(float(ans.per[got[k]]), 6)
                out.append((tx, r, [round(t, 6), per, None if lv is None else round(lv, 2)]))
        return out
