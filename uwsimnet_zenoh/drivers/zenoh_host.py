"""Attach a real-modem `Driver` (drivers/base.py) to a modem's Zenoh keys: the HIL swap, driver side.

    host = DriverHost(session, world, "bravo-modem", EvoLogicsDriver("192.168.0.10", 9200, "bravo-modem"))
    host.start()        # declares driver/real, waits for the simulator's driver/sim token to go
    ...
    host.close()        # the simulator serves the id again

* `modem/<id>/tx` -> `driver.send(dst, data, tag)`; malformed messages are answered `dropped` on `status`.
* `driver.on_frame` -> `modem/<id>/rx` ({src, dst, data, seq (per driver, counting), t_tx, t_rx});
  times are the broker's simulation time when its `clock` is heard, else seconds since the host started.
* `driver.on_status` -> `modem/<id>/status` (same vocabulary as the simulator's modems).
* `modem/<id>/info` (queryable) -> `driver.info()` plus `id`, `kind: real`, `world`, `edge`.

rx and status leave through the same `bus.endpoint.ModemEndpoint` as the simulator's modems (BLOCK
congestion control, the modem's outbox): the driver's I/O thread never waits on Zenoh, and what a consumer
that does not keep up lost is counted on `info` (`edge`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import Any

import zenoh
from uwsimnet_gli import wire
from uwsimnet_gli.wire import Keys

from ..bus.endpoint import ModemEndpoint
from .base import Driver, RxFrame, TxStatus

log = logging.getLogger("uwsimnet.drivers.host")


class DriverHost:
    def __init__(self, session: zenoh.Session, world: str, dev: str, driver: Driver) -> None:
        self.session = session
        self.keys = Keys(world)
        self.id = dev
        self.driver = driver
        self.counters = {"tx": 0, "rx": 0, "status": 0, "bad": 0}
        self._seq = 0
        self._t0 = time.time()
        self._clock: tuple[float, float, float] | None = None
        self._ents: list[Any] = []
        self._token: Any = None
        self._sim_gone = threading.Event()
        self._sim_present = False

    def now(self) -> float:
        c = self._clock
        if c is None:
            return time.time() - self._t0
        t, wall, speed = c
        return t + (time.time() - wall) * speed

    def start(self, wait_sim: float = 5.0) -> bool:
        """Declare `driver/real`, wait (up to `wait_sim` s) for the simulator to step back, then serve.
        Returns False if the sim token was still there at the deadline (served anyway)."""
        s, k, dev = self.session, self.keys, self.id
        self.driver.on_frame.append(self._on_frame)
        self.driver.on_status.append(self._on_status)
        self._ents.append(s.declare_subscriber(k.clock, self._on_clock))
        self._ents.append(s.liveliness().declare_subscriber(k.driver(dev, "sim"), self._on_sim, history=True))
        self._ep = ModemEndpoint(s, k, dev)
        self._token = s.liveliness().declare_token(k.driver(dev, "real"))
        time.sleep(0.05)                      # let the history of driver/sim arrive
        deadline = time.monotonic() + wait_sim
        while time.monotonic() < deadline and self._sim_present:
            time.sleep(0.01)
        ok = not self._sim_present
        if not ok:
            log.warning("%s: the simulator still holds driver/sim after %.1f s; serving anyway", dev, wait_sim)
        self._ents.append(s.declare_subscriber(k.tx(dev), self._on_tx))
        self._ents.append(s.declare_queryable(k.info(dev), self._on_info))
        return ok

    def close(self) -> None:
        for fn, lst in ((self._on_frame, self.driver.on_frame), (self._on_status, self.driver.on_status)):
            with contextlib.suppress(ValueError):
                lst.remove(fn)
        for e in (*self._ents, self._token):
            if e is not None:
                with contextlib.suppress(Exception):
                    e.undeclare()
        ep = getattr(self, "_ep", None)
        if ep is not None:
            ep.close(1.0)
        self._ents = []
        self._token = None

    def __enter__(self) -> DriverHost:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- Zenoh side -------------------------------------------------------------------------------
    def _on_sim(self, sample: zenoh.Sample) -> None:
        self._sim_present = sample.kind == zenoh.SampleKind.PUT

    def _on_clock(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(Exception):
            m = wire.unpack(sample.payload.to_bytes(), wire.MAX_SMALL_MESSAGE)
            self._clock = (float(m["t"]), time.time(), 0.0 if m.get("paused") else float(m.get("speed", 1.0)))

    def _on_tx(self, sample: zenoh.Sample) -> None:
        try:
            req = wire.decode_tx(sample.payload.to_bytes())
        except wire.CodecError as e:
            self.counters["bad"] += 1
            self._ep.status(e.tag, "dropped", e.reason, self.now())
            return
        self.counters["tx"] += 1
        self.driver.send(req.dst, req.data, req.tag)

    def _on_info(self, query: zenoh.Query) -> None:
        with query:
            try:
                info = dict(self.driver.info())
            except Exception as e:  # noqa: BLE001
                info = {"error": str(e)}
            info["host_counters"] = dict(self.counters)
            # tx messages go to the driver on Zenoh's thread, with no lane: nothing waits, nothing refused
            info = self._ep.info(info, kind="real", world=self.keys.world, t=self.now(),
                                 ingress={"n": self.counters["tx"], "queued": 0, "refused": 0})
            if info.get("address") is None:
                info["address"] = self.driver.address
            query.reply(self.keys.info(self.id), wire.pack(_plain(info)))

    # -- driver side (its I/O thread) -------------------------------------------------------------
    def _on_frame(self, f: RxFrame) -> None:
        self.counters["rx"] += 1
        seq, self._seq = self._seq, self._seq + 1
        t = self.now()
        self._ep.rx(int(f.src), int(f.dst), bytes(f.data), seq, t, t, msg=_rx_msg(f.meta))

    def _on_status(self, st: TxStatus) -> None:
        self.counters["status"] += 1
        self._ep.status(st.tag, st.event, st.reason, self.now())


def _rx_msg(meta: dict[str, Any] | None) -> dict[str, Any] | None:
    """The kind of message a real modem said it received (driver meta: kind, flag, pid) and the sending
    application's seq when the frame carries one (meta aseq: a SimplePacket's) as the wire's rx fields; None
    if it said nothing.  Burst data passed through in data mode counts as burst."""
    if not meta:
        return None
    kind = "burst" if meta.get("kind") == "data" else meta.get("kind")
    m = {"kind": kind, "flag": meta.get("flag") if kind == "im" else None, "pid": meta.get("pid"),
         "aseq": meta.get("aseq")}
    try:
        return wire.check_msg(m)
    except ValueError:
        return None


def _plain(x: Any) -> Any:
    """Something msgpack can carry (driver info may hold tuples, sets, enums...)."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple | set):
        return [_plain(v) for v in x]
    if x is None or isinstance(x, bool | int | float | str | bytes):
        return x
    return str(x)
