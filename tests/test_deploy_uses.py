"""The access-control rules are right by construction: every key the real programs declare (recorded
on a stand-in session) is one `uwsimnet_gli.wire.USES` grants that program, and - for the programs that
declare everything at start - every key USES grants it is one it declares (nothing granted for nothing).
deploy/render.py builds each role's rules from USES (tests/test_deploy.py); tests/test_deploy_matrix.py
runs the commands under those rules on real routers."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

pytest.importorskip("zenoh")

from conftest import device, scene, vehicle  # noqa: E402
from uwsimnet_gli import wire  # noqa: E402

WORLD = "lab"
BASE = f"{wire.PREFIX}/{WORLD}/"


class Recorder:
    """Just enough of zenoh.Session: records (capability, relative key) of every declaration."""

    def __init__(self, replies: dict[str, Any] | None = None) -> None:
        self.calls: list[tuple[str, str]] = []
        self.replies = replies or {}

    def _rec(self, cap: str, key: Any) -> SimpleNamespace:
        k = str(key)
        assert k.startswith(BASE), k
        self.calls.append((cap, k[len(BASE):]))
        return SimpleNamespace(undeclare=lambda: None, put=lambda *a, **kw: None)

    def declare_publisher(self, key: Any, **kw: Any) -> SimpleNamespace:
        return self._rec("publish", key)

    def put(self, key: Any, *a: Any, **kw: Any) -> None:
        self._rec("publish", key)

    def declare_subscriber(self, key: Any, *a: Any, **kw: Any) -> SimpleNamespace:
        return self._rec("subscribe", key)

    def declare_queryable(self, key: Any, *a: Any, **kw: Any) -> SimpleNamespace:
        return self._rec("serve", key)

    def get(self, key: Any, *a: Any, **kw: Any) -> list[Any]:
        self._rec("query", key)
        raw = self.replies.get(str(key)[len(BASE):])
        return [] if raw is None else [SimpleNamespace(ok=SimpleNamespace(
            payload=SimpleNamespace(to_bytes=lambda: raw), key_expr=str(key)))]

    def liveliness(self) -> SimpleNamespace:
        return SimpleNamespace(declare_token=lambda key, **kw: self._rec("token", key),
                               declare_subscriber=lambda key, *a, **kw: self._rec("watch", key),
                               get=lambda key, *a, **kw: (self._rec("watch", key), [])[1])

    def zid(self) -> str:
        return "0"


def covered(program: str, calls: list[tuple[str, str]], modems=(), vehicles=(), *, exact: bool) -> None:
    uses = wire.USES[program]
    granted = {(cap, k) for cap in wire.CAPABILITIES for t in uses.keys(cap) for k in wire.expand(t, modems, vehicles)}
    for cap, key in calls:
        assert any(c == cap and wire.includes(g, key) for c, g in granted), f"{program}: {cap} {key} not in USES"
    if exact:
        unused = {(c, g) for c, g in granted if not any(c == cap and wire.includes(g, k) for cap, k in calls)}
        assert not unused, f"{program}: USES grants {sorted(unused)} but it declares no such thing"


INFO_Y = wire.pack({"id": "y", "address": 3, "bitrate": 1000.0, "tx_channel": 0, "t": 0.0})


def test_broker_declares_what_uses_grants_it():
    from uwsimnet_zenoh.bus.broker import Broker
    from uwsimnet_zenoh.engine.network import Network
    from uwsimnet_zenoh.kernel.realtime import RealtimeClock

    net = Network(scene([vehicle("va", (0, 0, 0), device("a", 1)), vehicle("vb", (10, 0, 0), device("b", 2))]))
    s = Recorder()
    b = Broker(s, net, RealtimeClock(net.sched), world=WORLD)
    b.start()
    for dev in ("a", "b"):
        s.put(b.keys.status(dev), b"")           # the `dropped` status answer (bus/broker.py)
    s.declare_publisher(b.keys.pose("va"))       # scene-driven vehicles' poses (declared when moving)
    b.close()
    covered("broker", s.calls, exact=True)


def test_driver_host_declares_what_uses_grants_it():
    from uwsimnet_zenoh.drivers.zenoh_host import DriverHost

    s = Recorder()
    drv = SimpleNamespace(on_frame=[], on_status=[])
    host = DriverHost(s, WORLD, "y", drv)
    host.start(wait_sim=0.0)
    s.get(host.keys.info("y"))                   # `uwsimnet driver serial` without --address asks info
    host.close()
    covered("driver", s.calls, ["y"], exact=True)


def test_zenoh_backend_declares_what_uses_grants_it():
    from uwsimnet_zenoh.drivers.zenoh_backend import ZenohBackend

    s = Recorder({"modem/y/info": INFO_Y})
    ZenohBackend(s, WORLD, "y", timeout=1.0)
    covered("backend", s.calls, ["y"], exact=True)


def test_kinematic_vehicles_declare_what_uses_grants_them():
    from uwsimnet_zenoh.bus.kinematic import KinematicRunner
    from uwsimnet_zenoh.mobility.kinematic import KinematicVehicle

    s = Recorder()
    r = KinematicRunner(s, WORLD, [KinematicVehicle("vb", [0, 0, 0]), KinematicVehicle("vc", [1, 0, 0])])
    r.close()
    covered("vehicles", s.calls, vehicles=["vb", "vc"], exact=True)


def test_gli_world_and_modem_declare_what_uses_grants_them():
    from uwsimnet_gli.world import World

    s = Recorder()
    w = World(WORLD, session=s)
    w.modem("a")
    covered("modem", s.calls, ["a"], exact=True)
    for program, call, kw in (("pose", lambda: w.publish_pose("va", (0, 0, 0)), {"vehicles": ["va"]}),
                              ("command", lambda: w.command_vehicle("va", stop=True), {"vehicles": ["va"]}),
                              ("clock", lambda: w.clock(timeout=0), {}),
                              ("control", lambda: w.control_all("state", timeout=0), {}),
                              ("info", lambda: w.modem("a").info(timeout=0), {"modems": ["a"]})):
        s.calls.clear()
        call()
        calls = [c for c in s.calls if program != "info" or c[0] == "query"]   # info: a new Modem declares too
        covered(program, calls, exact=True, **kw)
    w.close()


def test_access_refusals_name_what_would_be_dropped():
    access = {"identity": "app-a", "role": "app", "world": WORLD,
              "allow": {"publish": ["modem/a/tx"], "subscribe": ["modem/a/rx", "modem/a/status"],
                        "watch": ["modem/a/driver/*"]}}
    assert wire.access_refusals(access, "modem", WORLD, ["a"]) == []
    assert wire.access_refusals(access, "modem", WORLD, ["b"])[0] == "publish uwsimnet/lab/modem/b/tx"
    assert wire.access_refusals(access, "modem", "other", ["a"])      # another world: nothing allowed
    assert wire.access_refusals(None, "modem", WORLD, ["b"]) == []     # no access section: no check
    msg = wire.refusal_message(access, wire.access_refusals(access, "listen", WORLD, ["*"]))
    assert msg.startswith("app-a (role app) may not subscribe uwsimnet/lab/modem/*/rx and 1 more")
