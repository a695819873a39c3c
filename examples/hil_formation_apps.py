"""The HIL formation's applications in real time, over Zenoh (the virtual-time version is
`python -m uwsimnet_zenoh.experiments hil-formation`; docs/paper-hil.md).

    uwsimnet run scenes/paper/hil-formation-aloha.xml --clock realtime           # the simulator
    uwsimnet vehicles --vehicle leader=0,0,-5 --vehicle follower1=-1.5,0,-5 \\
        --vehicle follower2=0,-1.5,-5 --vehicle follower3=-1.5,-1.5,-5 --max-speed 0.3 --max-accel 0.1
    python examples/hil_formation_apps.py [-e tcp/127.0.0.1:7447] [--world hil-formation-aloha] [--duration 240]

`uwsimnet vehicles` stands for the BlueROVs (the leader's pose may as well come from the real vehicle:
stop its `--vehicle leader=...` and publish `pose/leader` from the robot).  This program runs the
operator, the leader's and the followers' applications, each on its own modem:

* operator: every 4 s sends the current waypoint to the leader (address 1);
* leader: on a waypoint, commands its vehicle (`vehicle/leader/cmd`); every 2 s broadcasts its position;
* followers: on the leader's position, command their vehicle to it plus their formation offset.

It prints each vehicle's waypoint distance error every 5 s and writes them to out/hil-formation-rt.csv.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import struct
import threading
import time
from pathlib import Path

import msgpack
from uwsimnet_gli import World

from uwsimnet_zenoh.experiments.hil_formation import (
    DEPTH,
    LEADER_PERIOD,
    OPERATOR,
    OPERATOR_PERIOD,
    PAYLOAD,
    VEHICLES,
    _waypoint_at,
)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-e", "--endpoint", default="tcp/127.0.0.1:7447")
    ap.add_argument("--world", default="hil-formation-aloha")
    ap.add_argument("--duration", type=float, default=240.0)
    a = ap.parse_args()
    with World(a.world, connect=a.endpoint) as w:
        s = w.session
        poses: dict[str, tuple[float, float, float]] = {}
        subs = [s.declare_subscriber(f"uwsimnet/{a.world}/pose/{n}",
                                     lambda smp, n=n: poses.__setitem__(n, tuple(msgpack.unpackb(
                                         smp.payload.to_bytes())["p"])))
                for n in VEHICLES]
        modems = {n: w.modem(f"{n}-modem") for n in VEHICLES}
        op = w.modem(f"{OPERATOR[0]}-modem")

        def cmd(name: str, body: dict) -> None:
            s.put(f"uwsimnet/{a.world}/vehicle/{name}/cmd", msgpack.packb(body))

        def pad(b: bytes) -> bytes:
            return b + bytes(PAYLOAD - len(b))

        current: dict[str, tuple[float, ...]] = {}

        @modems["leader"].on_receive
        def _leader(f) -> None:
            if f.data[:1] == b"W":
                wp = struct.unpack("<3f", f.data[1:13])
                if current.get("leader") != wp:
                    current["leader"] = wp
                    cmd("leader", {"waypoint": list(wp)})

        for name in VEHICLES:
            if name == "leader":
                continue

            def _follower(f, name=name) -> None:
                if f.data[:1] == b"P":
                    lp = struct.unpack("<3f", f.data[1:13])
                    off = VEHICLES[name][1]
                    cmd(name, {"waypoint": [lp[0] + off[0], lp[1] + off[1], lp[2] + off[2]]})
            modems[name].on_receive(_follower)

        stop = threading.Event()
        t0 = time.monotonic()

        def every(period: float, fn) -> None:
            while not stop.wait(period):
                fn()

        def operator() -> None:
            op.send(VEHICLES["leader"][0], pad(b"W" + struct.pack("<3f", *_waypoint_at(time.monotonic() - t0))))

        def leader() -> None:
            p = poses.get("leader")
            if p is not None:
                modems["leader"].send(255, pad(b"P" + struct.pack("<3f", *p)))

        threads = [threading.Thread(target=every, args=(OPERATOR_PERIOD, operator), daemon=True),
                   threading.Thread(target=every, args=(LEADER_PERIOD, leader), daemon=True)]
        for t in threads:
            t.start()
        out = Path("out/hil-formation-rt.csv")
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            with out.open("w") as fh:
                fh.write("t," + ",".join(VEHICLES) + "\n")
                while (now := time.monotonic() - t0) < a.duration:
                    wp = _waypoint_at(now)
                    errs = []
                    for n, (_, off) in VEHICLES.items():
                        p = poses.get(n)
                        target = (wp[0] + off[0], wp[1] + off[1], DEPTH + off[2])
                        errs.append(math.dist(p, target) if p else float("nan"))
                    fh.write(f"{now:.1f}," + ",".join(f"{e:.3f}" for e in errs) + "\n")
                    if int(now * 10) % 50 == 0:
                        print(f"t={now:5.1f} s  " + "  ".join(f"{n}={e:.2f} m" for n, e in zip(VEHICLES, errs,
                                                                                              strict=True)),
                              flush=True)
                    time.sleep(0.1)
        except KeyboardInterrupt:
            pass
        finally:
            stop.set()
            for sub in subs:
                with contextlib.suppress(Exception):
                    sub.undeclare()
    print(f"errors in {out}")


if __name__ == "__main__":
    main()
