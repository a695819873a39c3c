"""`World`: a Zenoh session (client of the local router) plus the key space of one simulated world."""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from .records import read_map
from .wire import (
    ACCESS_KEY,
    DEFAULT_ENDPOINT,
    PREFIX,
    Keys,
    access_refusals,
    check_chunk,
    encode_pose,
    is_chunk,
    pack,
    refusal_message,
)


class GliError(RuntimeError):
    """No simulator/router reachable, no reply, an ambiguous world, a refused control request."""


def client_config(connect: str | Sequence[str] = DEFAULT_ENDPOINT, *, timeout_ms: int = 2000) -> zenoh.Config:
    """Client mode, connected to `connect` only (no multicast scouting)."""
    endpoints = [connect] if isinstance(connect, str) else list(connect)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(endpoints))
    conf.insert_json5("connect/timeout_ms", str(int(timeout_ms)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def load_config(config_file: str | None = None, connect: str | Sequence[str] | None = None, *,
                timeout_ms: int = 2000) -> zenoh.Config:
    """A client configuration: `config_file`, else $ZENOH_CONFIG, else `client_config()`; `connect`
    (when given) replaces the file's connect endpoints.  Use it to log in with TLS and user/password:
    `World(config=load_config("/etc/uwsimnet/robot1/clients/robot1-app.json5"))`."""
    import os  # noqa: PLC0415

    path = config_file or os.environ.get("ZENOH_CONFIG") or None
    if path is None:
        return client_config(connect or DEFAULT_ENDPOINT, timeout_ms=timeout_ms)
    try:
        conf = zenoh.Config.from_file(path)
        if connect:
            endpoints = [connect] if isinstance(connect, str) else list(connect)
            conf.insert_json5("connect/endpoints", json.dumps(endpoints))
    except zenoh.ZError as e:
        raise GliError(f"{path}: {' '.join(str(e).split())}") from None
    return conf


def config_endpoints(conf: zenoh.Config) -> list[str]:
    """The connect endpoints of a client configuration (what an error message names)."""
    try:
        v = json.loads(conf.get_json("connect/endpoints"))
    except (zenoh.ZError, ValueError):
        return []
    if isinstance(v, dict):
        v = v.get("client") or []
    return [str(e) for e in v] if isinstance(v, list) else []


def config_access(conf: zenoh.Config) -> dict[str, Any] | None:
    """The access section (`metadata.uwsimnet`) of a configuration rendered by `uwsimnet deploy render`."""
    try:
        v = json.loads(conf.get_json("metadata"))
    except (zenoh.ZError, ValueError):
        return None
    a = v.get(ACCESS_KEY) if isinstance(v, dict) else None
    return a if isinstance(a, dict) else None


def is_clock(m: Any) -> bool:
    """Is `m` a usable `clock` sample ({t, epoch, speed, paused}: a finite `t`, a positive `speed` if any)?"""
    if not isinstance(m, dict):
        return False
    t, speed = m.get("t"), m.get("speed", 1.0)
    return (isinstance(t, int | float) and not isinstance(t, bool) and math.isfinite(t)
            and isinstance(speed, int | float) and speed > 0)


def sim_time(sample: dict[str, Any]) -> float:
    """Simulation time now from a `clock` sample (`is_clock`): the one formula, the inverse of the broker's
    `epoch` (kernel/realtime.py: wall time of simulation time 0 at the current speed); `t` while paused."""
    if sample.get("paused") or not isinstance(sample.get("epoch"), int | float):
        return float(sample["t"])
    return (time.time() - float(sample["epoch"])) * float(sample.get("speed") or 1.0)


def discover_worlds(session: zenoh.Session, timeout: float = 2.0) -> list[str]:
    """Names of the worlds whose brokers answer `uwsimnet/*/control/state`."""
    found = set()
    for r in session.get(f"{PREFIX}/*/control/state", timeout=timeout):
        if r.ok is not None:
            parts = str(r.ok.key_expr).split("/")
            if len(parts) >= 2:
                found.add(parts[1])
    return sorted(found)


class World:
    """One simulated world on Zenoh.

        with World("acoustic-apps") as world:           # connects to tcp/127.0.0.1:7447 (client mode)
            modem = world.modem("alpha-modem")
            modem.send(2, b"hello")

    `name=None` asks the brokers reachable through the router which worlds exist and takes the only one.
    Pass `session=` to reuse a session you opened (it is then not closed by `close()`), or `config=` for a
    full Zenoh configuration (TLS, other endpoints; see `load_config`).  Without either, the environment
    variable ZENOH_CONFIG names a client configuration file to use (`connect=` replaces its endpoints).
    """

    def __init__(self, name: str | None = None, *, connect: str | Sequence[str] | None = None,
                 config: zenoh.Config | None = None, session: zenoh.Session | None = None,
                 timeout: float = 2.0) -> None:
        self._own = session is None
        self.access: dict[str, Any] | None = None
        """What the deployment allows this identity (`metadata.uwsimnet` of a rendered configuration)."""
        if session is None:
            # no config: $ZENOH_CONFIG if set (connect replaces its endpoints), else client_config()
            conf = config if config is not None else load_config(None, connect)
            self.access = config_access(conf)
            try:
                session = zenoh.open(conf)
            except zenoh.ZError as e:
                where = ", ".join(config_endpoints(conf)) or "the configured endpoints"
                why = " ".join(str(e).split()).split(" at /")[0]            # no Rust source locations
                raise GliError(f"cannot connect to {where}: {why} (is `uwsimnet run` or `uwsimnet router`"
                               " running there, and are the TLS files and password right?)") from None
        self.session = session
        try:
            aw = (self.access or {}).get("world")
            if name is None and isinstance(aw, str) and is_chunk(aw):
                name = aw                   # the deployment's world (discovery would be refused)
            if name is None:
                worlds = discover_worlds(session, timeout)
                if len(worlds) != 1:
                    raise GliError("no simulated world answers; give the world name" if not worlds else
                                   f"several worlds answer ({', '.join(worlds)}); give one")
                name = worlds[0]
            self.name = check_chunk(name, "world")
        except BaseException:
            self._close_session()
            raise
        self.keys = Keys(self.name)
        self._modems: list[Any] = []
        self._pose_pubs: dict[str, Any] = {}
        self._cmd_pubs: dict[str, Any] = {}
        self._clock_sub: Any = None
        self._clock: dict[str, Any] | None = None
        self._clock_cond = threading.Condition()
        self._closed = False

    # -- lifecycle -------------------------------------------------------------------------------
    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything this world declared; close the session if this object opened it."""
        if self._closed:
            return
        self._closed = True
        for m in list(self._modems):
            m.close()
        for p in (*self._pose_pubs.values(), *self._cmd_pubs.values()):
            _undeclare(p)
        _undeclare(self._clock_sub)
        self._close_session()

    def _close_session(self) -> None:
        if self._own:
            with contextlib.suppress(Exception):
                self.session.close()

    def check(self, program: str, modems: Sequence[str] = (), vehicles: Sequence[str] = ()) -> None:
        """GliError (one line) if this identity's access control would drop what `program` (a key of
        `uwsimnet_gli.wire.USES`: modem, listen, info, pose, command, control, trace, ...) declares."""
        refused = access_refusals(self.access, program, self.name, modems, vehicles)
        if refused:
            raise GliError(refusal_message(self.access, refused))

    # -- modems ----------------------------------------------------------------------------------
    def modem(self, dev: str, **kw: Any):
        """A `Modem` handle for dccommsId `dev` (see uwsimnet_gli.modem.Modem)."""
        from uwsimnet_gli.modem import Modem

        return Modem(self, dev, **kw)

    # -- poses -----------------------------------------------------------------------------------
    def publish_pose(self, vehicle: str, p: Sequence[float], *, v: Sequence[float] | None = None,
                     q: Sequence[float] | None = None, t: float | None = None) -> None:
        """Publish a pose sample of `vehicle` (m, m/s, quaternion x y z w) on `pose/<vehicle>`."""
        pub = self._pose_pubs.get(vehicle)
        if pub is None:
            pub = self._pose_pubs[vehicle] = self.session.declare_publisher(
                self.keys.pose(check_chunk(vehicle, "vehicle")))
        pub.put(encode_pose(p, v=v, q=q, t=t))

    # -- simulation time -------------------------------------------------------------------------
    def clock(self, timeout: float = 2.0) -> dict[str, Any] | None:
        """The last `clock` sample ({t, epoch, speed, paused}); waits up to `timeout` for the first one."""
        if self._clock_sub is None:
            self._clock_sub = self.session.declare_subscriber(self.keys.clock, self._on_clock)
        with self._clock_cond:
            self._clock_cond.wait_for(lambda: self._clock is not None, timeout)
            return self._clock

    def _on_clock(self, sample: zenoh.Sample) -> None:
        try:
            m = read_map(sample.payload.to_bytes())
        except Exception:  # noqa: BLE001
            return
        if is_clock(m):
            with self._clock_cond:
                self._clock = m
                self._clock_cond.notify_all()

    def sim_time(self, timeout: float = 2.0) -> float | None:
        """Current simulation time estimated from the wall clock and the last clock sample."""
        c = self.clock(timeout)
        return None if c is None else sim_time(c)

    # -- control ---------------------------------------------------------------------------------
    def control(self, op: str, timeout: float = 2.0, **request: Any) -> dict[str, Any]:
        """Run a control operation (state, pause, resume, move, add_device, remove_device); the first
        successful reply, or GliError with the broker's error."""
        replies = self.control_all(op, timeout=timeout, **request)
        if not replies:
            raise GliError(f"control/{op}: no reply from world {self.name!r}")
        for r in replies:
            if r.get("ok"):
                return r
        raise GliError(f"control/{op}: {replies[0].get('error', 'refused')}")

    def command_vehicle(self, vehicle: str, **command: Any) -> None:
        """Send a command to a kinematic vehicle (`uwsimnet vehicles`, docs/runtime.md) on
        `vehicle/<name>/cmd`: e.g. `waypoint=[10, 0, 5]`, `v=[1, 0, 0]`, `stop=True`."""
        pub = self._cmd_pubs.get(vehicle)
        if pub is None:
            pub = self._cmd_pubs[vehicle] = self.session.declare_publisher(self.keys.vehicle_cmd(vehicle))
        pub.put(pack(command))

    def control_all(self, op: str, timeout: float = 2.0, **request: Any) -> list[dict[str, Any]]:
        """Every broker's reply (several brokers serve a world split by channels)."""
        out = []
        for r in self.session.get(self.keys.control(check_chunk(op, "operation")), payload=pack(request),
                                  timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE):
            if r.ok is not None:
                try:
                    m = read_map(r.ok.payload.to_bytes())
                except Exception:  # noqa: BLE001
                    continue
                if isinstance(m, dict):
                    out.append(m)
        return out


def _undeclare(e: Any) -> None:
    if e is not None:
        with contextlib.suppress(Exception):
            e.undeclare()
