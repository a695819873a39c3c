"""Shared helpers: scenes built in code, and a network run that records its trace in memory."""

from __future__ import annotations

import ast
import functools
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.scene.model import Channel, Device, ErrorModel, Flow, MacSpec, Scene, Simulation, Vehicle

# Hypothesis on a loaded 2-core CI machine: the same number of examples and the same checks on the data, but no
# check that measures the machine's speed (the per-example deadline and "input generation is slow").
settings.register_profile("uwsimnet", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("uwsimnet")

# A suite started as a script's background job (`make test &`, no job control) inherits SIGINT ignored (POSIX),
# and so did every process a test started: helper scripts and the sweep then never stopped on SIGINT (the
# idle series' runs 5 and 6).  The tests' processes take SIGINT as in an interactive run.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# `pytest -m core`: the tests of the sans-IO core alone (docs/architecture.md), chosen by what a test module
# imports, so a new test file is classified as it is written: only rooms below the sans-IO line
# (tests/test_architecture.py's LAYERS), no Zenoh, no processes, sockets, threads or event loops, and no other
# test module (those that share a live broker's helpers).  Seconds, not minutes: the inner loop of a core change.
CORE_ROOMS = frozenset({"errors", "_native", "kernel", "trace", "mobility", "phy", "mac", "scene", "traffic",
                        "engine", "analysis", "ros2"})
NOT_CORE = frozenset({"zenoh", "uwsimnet_gli", "subprocess", "socket", "threading", "multiprocessing", "asyncio",
                      "selectors", "http", "urllib", "dask", "distributed"})
HELPERS = frozenset({"conftest", "metrics_reference"})     # test helpers that are themselves core


@functools.cache
def is_core(path: str) -> bool:
    """Does the test module at `path` import only the core (see CORE_ROOMS)?"""
    tree = ast.parse(Path(path).read_text(encoding="utf-8"), path)
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            names = [a.name for a in n.names]
        elif isinstance(n, ast.ImportFrom) and not n.level:
            names = [n.module or ""]
        else:
            continue
        for name in names:
            top, _, rest = name.partition(".")
            if top == "uwsimnet_zenoh":
                if rest.split(".")[0] not in CORE_ROOMS:
                    return False
            elif top in NOT_CORE or (top not in HELPERS and (Path(path).parent / f"{top}.py").exists()):
                return False
    return True


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if is_core(str(item.path)):
            item.add_marker(pytest.mark.core)


def device(dev_id: str, address: int, ch: int = 0, rx: int | None = None, **kw: Any) -> Device:
    error = kw.pop("error", None)
    mac = kw.pop("mac", None)
    extra = {}
    if error is not None:
        extra["error"] = ErrorModel(expr=error[0], unit=error[1]) if isinstance(error, tuple) else \
            ErrorModel(expr=error, unit="packet")
    if mac is not None:
        extra["mac"] = MacSpec(name=mac[0], params=mac[1]) if isinstance(mac, tuple) else MacSpec(name=mac)
    return Device(dccomms_id=dev_id, address=address, tx_channel=ch, rx_channel=ch if rx is None else rx,
                  **extra, **kw)


def scene(vehicles: list[Vehicle], flows: list[Flow] = (), channels: list[Channel] | None = None,
          duration: float = 10.0, seed: int = 1) -> Scene:
    return Scene(name="test", simulation=Simulation(duration=duration, seed=seed),
                 channels=tuple(channels or [Channel(id=0, prop_s_per_m=1 / 1500, min_prop_s=0.0)]),
                 vehicles=tuple(vehicles), flows=tuple(flows))


def vehicle(name: str, pos: tuple[float, float, float], *devices: Device, **kw: Any) -> Vehicle:
    return Vehicle(name=name, position=pos, devices=tuple(devices), **kw)


class Recorded:
    """A network plus its trace records, kept in memory."""

    def __init__(self, sc: Scene, **kw: Any) -> None:
        self.net = Network(sc, **kw)
        self.records: list[dict] = []
        self.net.tracer.add(self.records.append)

    def run(self, until: float | None = None) -> Recorded:
        self.net.run(until)
        return self

    def ev(self, ev: str, **match: Any) -> list[dict]:
        return [r for r in self.records if r["ev"] == ev and all(r.get(k) == v for k, v in match.items())]


@pytest.fixture
def record():
    return Recorded


def netns_unavailable(what: str, *, openssl: bool = False) -> str | None:
    """Why network-namespace tests cannot run here (None: they can); `what` names the test in the reason."""
    if sys.platform != "linux":
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return f"needs root (network namespaces): run the suite as root to include {what}"
    if shutil.which("ip") is None:
        return "needs iproute2 (`ip`)"
    r = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True)
    if r.returncode != 0:
        return f"`ip netns` does not work here: {r.stderr.strip()}"
    if openssl and shutil.which("openssl") is None:
        return "needs openssl (TLS certificates)"
    return None
