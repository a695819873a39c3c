"""The paper's HIL formation experiment (Sec. 3.3, Fig. 9) as it runs in a lab: separate processes on a
real-time clock over Zenoh, CS-ALOHA and S-FAMA side by side.

    uwsimnet experiment hil-formation [--duration 240] [--out out/hil-formation]

Per MAC, each in its own process (logs in OUT/logs/):

* the channel broker: `uwsimnet run scenes/paper/hil-formation-<mac>.xml --clock realtime`;
* the followers' BlueROVs: `uwsimnet vehicles` (kinematic vehicles on `vehicle/<name>/cmd`);
* the leader BlueROV: `hil_apps robot`, an outside process publishing the tracked pose on `pose/leader`
  (where the paper had the real robot and its Aruco tracker);
* five applications (`hil_apps app NAME`), one per robot plus the operator, each on its own modem
  through uwsimnet_gli.

plus one Zenoh router for all.  This process records every vehicle's pose at 10 Hz of its world's
simulation time, computes Fig. 9's errors, and compares them with the virtual-time model of the same
scene (`hil_formation.simulate`), drawn dashed in the figure.  Both worlds run at once (the load is a
few per cent of a core), so a 240 s experiment takes about 4 minutes.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import re
import time
from pathlib import Path
from typing import Any

from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys, parse

from ..analysis import read_trace
from ..bus.clock import WorldClock
from ..bus.session import make_config, open_session
from ..errors import UserError
from ..trace.events import finite
from . import hil_formation as h
from . import hil_spec as spec
from . import sidecar
from .processes import PY, ProcessError, Processes, Progress

TICK = 0.1


def _uwsimnet(*args: str) -> list[str]:
    return [PY, "-m", "uwsimnet_zenoh.cli", *args]


def _apps(*args: str) -> list[str]:
    return [PY, "-m", "uwsimnet_zenoh.experiments.hil_apps", *args]


def start_world(procs: Processes, mac: str, endpoint: str, out: Path, duration: float, speed: float,
                traffic: str = spec.DEFAULT_TRAFFIC) -> str:
    world = spec.world_name(mac, traffic)
    scene = spec.scene_path(mac, traffic)
    procs.start(f"{mac}-broker", _uwsimnet("run", str(scene), "--clock", "realtime", "--connect", endpoint,
                                           "--duration", f"{duration + 60:g}", "--speed", f"{speed:g}",
                                           "--trace", str(out / f"{mac}.trace.jsonl")),
                ready="uwsimnet: running")
    followers = [f"--vehicle={n}={off[0]:g},{off[1]:g},{spec.DEPTH:g}"
                 for n, (_, off) in spec.VEHICLES.items() if n != "leader"]
    procs.start(f"{mac}-vehicles", _uwsimnet("vehicles", "--world", world, "--connect", endpoint, *followers,
                                             "--max-speed", f"{spec.MAX_SPEED:g}", "--max-accel", f"{spec.MAX_ACCEL:g}",
                                             "--rate", f"{10 * speed:g}"),      # 10 poses per simulated second
                ready="uwsimnet: vehicles ready")
    procs.start(f"{mac}-robot", _apps("robot", "--world", world, "--connect", endpoint, "--rate", f"{15 * speed:g}"),
                ready="ready in")
    for name in (spec.OPERATOR[0], *spec.VEHICLES):
        procs.start(f"{mac}-{name}", _apps("app", name, "--world", world, "--connect", endpoint),
                    ready="ready in")
    return world


class Recorder:
    """Every vehicle's latest pose per world (Zenoh callback) and Fig. 9's errors sampled every TICK s of
    that world's simulation time."""

    def __init__(self, session: Any, worlds: dict[str, str], until: float) -> None:
        self.until = until
        self.clocks = {mac: WorldClock(session, Keys(w)) for mac, w in worlds.items()}   # mac -> world name
        self.poses: dict[str, dict[str, spec.Vec]] = {mac: {} for mac in worlds}
        self.res = {mac: {"mac": mac, "t": [], "error": {n: [] for n in spec.VEHICLES}} for mac in worlds}
        self._next = dict.fromkeys(worlds, 0.0)
        by_world = {w: mac for mac, w in worlds.items()}

        def on_pose(sample: Any) -> None:
            k = parse(sample.key_expr)
            if k is None or k.kind != "pose" or k.world not in by_world or k.name is None:
                return
            with contextlib.suppress(wire.CodecError):
                self.poses[by_world[k.world]][k.name] = wire.decode_pose(sample.payload.to_bytes()).p

        self._sub = session.declare_subscriber("uwsimnet/*/pose/*", on_pose)

    def sample(self) -> float:
        """Record what is due; the least simulation time over the worlds."""
        least = float("inf")
        for mac, clock in self.clocks.items():
            t = clock.now()
            if t is None:                                    # no clock sample yet
                least = 0.0
                continue
            least = min(least, t)
            if t < self._next[mac] or t > self.until:
                continue
            errs = spec.formation_errors(t, self.poses[mac])
            if len(errs) < len(spec.VEHICLES):
                continue                                     # not every vehicle has a pose yet
            r = self.res[mac]
            r["t"].append(t)
            for n, e in errs.items():
                r["error"][n].append(e)
            self._next[mac] = t + TICK
        return least

    def close(self) -> None:
        for c in self.clocks.values():
            c.close()
        with contextlib.suppress(Exception):
            self._sub.undeclare()


def run(out: Path, *, duration: float = spec.DURATION, speed: float = 1.0, traffic: str = spec.DEFAULT_TRAFFIC,
        figure: Path | None = None) -> dict[str, Any]:
    """Run both MACs in real time (about `duration` / `speed` s plus start-up; `speed` > 1 is for runs
    without hardware: every process follows the worlds' clocks); Fig. 9, summary.md/json in `out`.
    `traffic`: 'paper' (control frames + the Sec. 3.2 image flows) or 'control' (hil_spec.TRAFFIC)."""
    if importlib.util.find_spec("uwsimnet_gli") is None:      # the apps are uwsimnet_gli clients
        raise UserError("hil-formation: the applications need the uwsimnet_gli client: pip install -e"
                        " gli_clients/python (make does it)")
    out.mkdir(parents=True, exist_ok=True)
    with Processes(out / "logs") as procs:
        router = procs.start("router", _uwsimnet("router", "--listen", "tcp/127.0.0.1:0"), ready="listening on")
        endpoint = re.search(r"tcp/127\.0\.0\.1:\d+", router.output()).group(0)      # the port it was given
        worlds = {mac: start_world(procs, mac, endpoint, out, duration, speed, traffic) for mac in spec.PROTOCOLS}
        with open_session(make_config("client", connect=[endpoint])) as session:
            rec = Recorder(session, worlds, duration)
            try:
                with Progress("HIL formation, real time", total=duration) as bar:
                    while (least := rec.sample()) < duration:
                        procs.check_alive()
                        bar.update(least)
                        time.sleep(TICK / 4 / speed)
            finally:
                rec.close()
        bad = procs.stop_all()
    if bad:
        raise ProcessError("\n".join(bad))
    results = rec.res
    for mac, r in results.items():
        if not r["t"]:
            raise ProcessError(f"{mac}: no vehicle poses recorded before t={duration:g} s: too short a run for"
                               " the processes to start (give --duration 10 or more)")
    for mac, r in results.items():
        recs = list(read_trace(out / f"{mac}.trace.jsonl")[1])
        r["delivery"], r["timing"] = h.delivery(recs), h.timing(recs)
        h.write_errors(r, out / f"{mac}.errors.csv")
    # the model over the same window as the real-time record (which starts once every pose is known)
    model = {mac: h.window(h.simulate(mac, duration=duration, traffic=traffic), results[mac]["t"][0])
             for mac in spec.PROTOCOLS}
    st = {mac: h.stats(r) for mac, r in results.items()}
    st_model = {mac: h.stats(r) for mac, r in model.items()}
    for path in (out / "fig9-hil-formation.png", figure):
        if path is not None:
            h.plot(results, path, model=model)
    pace = "real time" if speed == 1.0 else f"real time x{speed:g}"
    lines = h.table(st, f"HIL formation, {pace} ({duration:g} s, separate processes over Zenoh),"
                        f" traffic '{traffic}'")
    lines += ["", "Virtual-time model of the same scene (dashed in the figure):", "",
              "| MAC | vehicle | mean error, real time (m) | mean error, model (m) | difference (m) |",
              "|---|---|---|---|---|"]
    for mac in spec.PROTOCOLS:
        for n in spec.VEHICLES:
            a, b = st[mac][n]["mean"], st_model[mac][n]["mean"]
            lines.append(f"| {spec.PROTOCOLS[mac]} | {n} | {a:.3f} | {b:.3f} | {a - b:+.3f} |")
    lines += ["", *h.timing_table({mac: r["timing"] for mac, r in results.items()})]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    summary = {"realtime": st, "virtual": st_model, "duration": duration, "speed": speed, "traffic": traffic}
    (out / "summary.json").write_text(json.dumps(finite(summary), indent=2, allow_nan=False))
    for path in (out / "fig9-hil-formation.png", figure):
        if path is not None:
            sidecar.write(path, finite(summary))      # the numbers docs/paper-hil.md states of the figure
    return st
