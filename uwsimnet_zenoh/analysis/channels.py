"""Per-channel metrics of a trace: what the medium carried and lost (one pass, O(1) per record).

    frames        tx events on the channel (data + control, retransmissions included)
    bytes         bytes put on air
    airtime       seconds of transmission (size * 8 / the sender's bit rate, from the meta), summed
    utilisation   airtime / duration (can exceed 1: transmissions overlap)
    received      rx events at receivers on the channel
    collisions    receiver drops with reason col or mult
    lost          receiver drops with reason prop, range or nopose
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

RX_LOSS = ("prop", "range", "nopose")
COLLISION = ("col", "mult")


def channel_metrics(records: Iterable[Mapping[str, Any]], meta: Mapping[str, Any]) -> dict[int, dict[str, Any]]:
    devices = meta.get("devices") or {}
    rate = {d: float(v.get("bitrate") or 0) for d, v in devices.items() if isinstance(v, Mapping)}
    out: dict[int, dict[str, Any]] = {}

    def slot(ch: int) -> dict[str, Any]:
        m = out.get(ch)
        if m is None:
            m = out[ch] = {"frames": 0, "bytes": 0, "airtime": 0.0, "received": 0, "collisions": 0, "lost": 0}
        return m

    for r in records:
        ev = r.get("ev")
        ch = r.get("ch")
        if not isinstance(ch, int) or ev not in ("tx", "rx", "drop"):
            continue
        m = slot(ch)
        if ev == "tx":
            m["frames"] += 1
            size = int(r.get("size") or 0)
            m["bytes"] += size
            br = rate.get(r.get("dev"), 0.0)
            if br > 0:
                m["airtime"] += size * 8.0 / br
        elif ev == "rx":
            m["received"] += 1
        elif r.get("reason") in COLLISION:
            m["collisions"] += 1
        elif r.get("reason") in RX_LOSS:
            m["lost"] += 1
    duration = meta.get("duration")
    for m in out.values():
        m["airtime"] = round(m["airtime"], 9)
        m["utilisation"] = round(m["airtime"] / duration, 9) if isinstance(duration, int | float) and duration > 0 \
            else None
    return dict(sorted(out.items()))
