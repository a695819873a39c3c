"""A Zenoh session configured as rmw_zenoh configures a ROS 2 node's (peer mode, connect tcp/localhost:PORT,
listen tcp/localhost:0, timestamping on, no multicast), driven by JSON lines on stdin, one JSON answer per
line on stdout. Plain zenoh + stdlib: it runs under eclipse-zenoh 1.4.0, 1.6.2 and the project's 1.10, so
tests can put ROS peers of the Zenoh versions rmw_zenoh ships next to the simulator.

    {"cmd": "open", "connect": "tcp/localhost:7447"}
    {"cmd": "lget", "key": "@ros2_lv/0/**"}                                -> {"keys": [...]}
    {"cmd": "sub", "name": "rx", "key": K}                                 (exact key, as a ROS subscriber)
    {"cmd": "adv_sub", "name": "tfs", "key": K}                            (history + late publishers; >= 1.6)
    {"cmd": "put", "key": K, "payload": HEX, "attachment": HEX | null}
    {"cmd": "take", "name": "rx", "n": 1, "timeout": 3}                    -> {"samples": [{key, payload, att}]}
    {"cmd": "get", "key": K}                                               -> {"replies": [[key, HEX], ...]}
    {"cmd": "close"}
"""

from __future__ import annotations

import importlib.metadata
import json
import queue
import sys
import time

import zenoh


def main() -> None:
    session = None
    subs: dict[str, queue.Queue] = {}
    keep: list = []
    pubs: dict[str, object] = {}
    out = sys.stdout
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req["cmd"]
        res: dict = {"ok": True}
        try:
            if cmd == "open":
                conf = zenoh.Config()
                for k, v in (("mode", "peer"), ("connect/endpoints", [req["connect"]]),
                             ("listen/endpoints", ["tcp/localhost:0"]), ("scouting/multicast/enabled", False),
                             ("timestamping/enabled", {"router": True, "peer": True, "client": True})):
                    conf.insert_json5(k, json.dumps(v))
                session = zenoh.open(conf)
                res["zid"] = str(session.zid())
                res["version"] = importlib.metadata.version("eclipse-zenoh")
            elif cmd == "lget":
                res["keys"] = sorted(str(r.ok.key_expr) for r in session.liveliness().get(req["key"], timeout=2.0)
                                     if r.ok is not None)
            elif cmd in ("sub", "adv_sub"):
                q: queue.Queue = queue.Queue()
                subs[req["name"]] = q

                def cb(sample, q=q):
                    att = sample.attachment
                    q.put({"key": str(sample.key_expr), "payload": sample.payload.to_bytes().hex(),
                           "att": None if att is None else att.to_bytes().hex()})
                if cmd == "sub":
                    keep.append(session.declare_subscriber(req["key"], cb))
                else:
                    import zenoh.ext as ext
                    keep.append(ext.declare_advanced_subscriber(
                        session, req["key"], cb, history=ext.HistoryConfig(detect_late_publishers=True),
                        subscriber_detection=True))
            elif cmd == "put":
                pub = pubs.get(req["key"])
                if pub is None:
                    pub = pubs[req["key"]] = session.declare_publisher(req["key"])
                att = req.get("attachment")
                if att is None:
                    pub.put(bytes.fromhex(req["payload"]))
                else:
                    pub.put(bytes.fromhex(req["payload"]), attachment=bytes.fromhex(att))
            elif cmd == "take":
                q = subs[req["name"]]
                got, deadline = [], time.monotonic() + float(req.get("timeout", 3.0))
                while len(got) < int(req.get("n", 1)):
                    try:
                        got.append(q.get(timeout=max(0.0, deadline - time.monotonic())))
                    except queue.Empty:
                        break
                res["samples"] = got
            elif cmd == "get":
                res["replies"] = [[str(r.ok.key_expr), r.ok.payload.to_bytes().hex()]
                                  for r in session.get(req["key"], timeout=2.0) if r.ok is not None]
            elif cmd == "close":
                break
            else:
                res = {"ok": False, "error": f"unknown command {cmd!r}"}
        except Exception as e:  # noqa: BLE001 - reported to the test
            res = {"ok": False, "error": f"{type(e).__name__}: {e}"}
        out.write(json.dumps(res) + "\n")
        out.flush()
    keep.clear()
    pubs.clear()
    if session is not None:
        session.close()
    out.write(json.dumps({"ok": True, "closed": True}) + "\n")
    out.flush()


if __name__ == "__main__":
    main()
