"""Every run ends with a true account (#21): on SIGINT/SIGTERM (virtual and realtime) the trace is whole,
ends with an `end` record at the actual end time, conserves every frame (one outcome per frame per
receiver, `stopped` for what was in flight), the summary is printed and the exit code is 0; a plug-in
that raises is reported once and the run ends with exit code 2, never silently, never 0.

The signal tests repeat 20 times (the cut last line was seen in 2 of 59 tries before).  They wait for
the run to be under way by what it wrote, not by a sleep tuned to this machine."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis import analyse, flow_metrics

ROOT = Path(__file__).resolve().parents[1]
UWSIMNET = [sys.executable, "-m", "uwsimnet_zenoh.cli"]
REPEAT = 20


def _device(dev: str, mac: int, extra: str = "") -> str:
    return f"""<CustomCommsDevice><dccommsId>{dev}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId><bitrate>10000</bitrate><maxDistance>5000</maxDistance>
      <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0.1</errorRateExpr></rateErrorModel>{extra}
      </CustomCommsDevice>"""


def scene(*, duration: float, clock: str = "virtual", tracing: str = "", mac: str = "", port: int = 0) -> str:
    world = f"<world>end{port}</world>" if port else ""
    return f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><duration>{duration:g}</duration><clock>{clock}</clock>{world}</simulation>
  {tracing}
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  <vehicle><name>a</name><position>0 0 0</position>{_device("a-m", 1, mac)}</vehicle>
  <vehicle><name>b</name><position>1000 0 0</position>{_device("b-m", 2, mac)}</vehicle>
  <vehicle><name>c</name><position>0 500 0</position>{_device("c-m", 3, mac)}</vehicle>
  <flow><name>ab</name><src>a-m</src><dst>2</dst><size>100</size><interval>0.5</interval></flow>
  <flow><name>bc</name><src>b-m</src><dst>255</dst><size>50</size><interval>0.7</interval>
    <arrival>poisson</arrival><start>0.13</start></flow>
  <flow><name>ca</name><src>c-m</src><dst>1</dst><size>20</size><interval>0.2</interval><start>0.29</start></flow>
</UWSimScene>"""


def _records(path: Path) -> list[dict]:
    text = path.read_text()
    assert text.endswith("\n"), "the last line is cut"
    return [json.loads(line) for line in text.splitlines()]       # every line whole JSON


def _check_stopped_trace(path: Path, signame: str) -> dict:
    recs = _records(path)
    end = recs[-1]
    assert end["ev"] == "end" and end["reason"] == "signal" and end["signal"] == signame
    assert all(r["ev"] != "end" for r in recs[:-1])
    assert end["t"] >= max(r["t"] for r in recs[1:-1])
    a = analyse(path, horizon=0.0)        # no grace: every frame has its outcome, none "in flight"
    assert a.conservation.ok, a.conservation.violations[:5]
    assert a.conservation.in_flight == []
    return end


def _wait_size(path: Path, n: int, p: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not (path.exists() and path.stat().st_size > n):
        assert p.poll() is None, p.communicate()
        assert time.monotonic() < deadline, "the run wrote nothing"
        time.sleep(0.02)


def _wait_record(path: Path, want, p: subprocess.Popen, timeout: float = 60.0) -> None:
    """Until a whole line of the trace satisfies `want` (the run is where the test needs it)."""
    deadline = time.monotonic() + timeout
    while True:
        text = path.read_text() if path.exists() else ""
        if any(want(json.loads(line)) for line in text[:text.rfind("\n") + 1].splitlines()):
            return
        assert p.poll() is None, p.communicate()
        assert time.monotonic() < deadline, "the run wrote no such record"
        time.sleep(0.05)


@pytest.mark.parametrize("pure", ["0", "1"])
def test_virtual_run_stopped_by_a_signal_ends_true_20_times(tmp_path, pure):
    """Compiled and pure Python: in pure Python a signal handler can run inside any Python code the engine
    calls, even a comparison heapq makes (a heap of events with a Python `__lt__` broke exactly so)."""
    sc = tmp_path / "long.xml"
    sc.write_text(scene(duration=1e6))
    for i in range(REPEAT):
        sig = (signal.SIGINT, signal.SIGTERM)[i % 2]
        trace = tmp_path / f"t{i}.jsonl"
        p = subprocess.Popen([*UWSIMNET, "run", str(sc), "--trace", str(trace)], cwd=ROOT, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             env={**os.environ, "UWSIMNET_PURE": pure})
        _wait_size(trace, 20_000 + 5_000 * i, p)       # a little further on each time
        p.send_signal(sig)
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, err
        assert "Traceback" not in err
        end = _check_stopped_trace(trace, sig.name)
        assert f"{end['t']:g} s simulated (stopped by {sig.name} of 1e+06 s)" in out
        assert "flow" in out.splitlines()[0]                        # the per-flow table came first
        m = flow_metrics(str(trace))
        assert m["ab"].enqueued > 0 and m["ab"].delivered > 0
        # report's rates are over the actual end: ab offers 100 B every 0.5 s from t=0, so over [0, end]
        # it offered 100 B x (floor(end / 0.5) + 1) (over the planned 1e6 s it would read ~0.2 B/s)
        assert m["ab"].window == (0.0, end["t"])
        assert m["ab"].offered == pytest.approx(100 * (math.floor(end["t"] / 0.5 + 1e-9) + 1) / end["t"])


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_realtime_run_stopped_by_a_signal_ends_true(tmp_path, sig):
    from test_broker_e2e import free_port

    for i in range(REPEAT // 2):
        port = free_port()
        sc = tmp_path / f"rt{i}.xml"
        sc.write_text(scene(duration=600, clock="realtime", port=port))
        trace = tmp_path / f"rt{i}.jsonl"
        p = subprocess.Popen([*UWSIMNET, "run", str(sc), "--trace", str(trace), "--listen",
                              f"tcp/127.0.0.1:{port}"], cwd=ROOT, text=True, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        line = ""
        deadline = time.monotonic() + 30
        while not line.startswith("uwsimnet: running"):
            line = p.stdout.readline()
            assert line or p.poll() is None, p.communicate()
            assert time.monotonic() < deadline
        running = time.monotonic()          # the clock started before "running" was printed
        _wait_record(trace, lambda r: r["ev"] == "enq" and r.get("flow") == "ca", p)   # on disk within ~1 s
        time.sleep(0.05 * i)                # a little further on each time: frames queued, on air, in reception
        lapse = time.monotonic() - running
        p.send_signal(sig)
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, err
        assert "Traceback" not in err
        end = _check_stopped_trace(trace, sig.name)
        assert lapse <= end["t"] < 60       # the wall clock's time at the stop (speed 1), not the last event's
        assert f"stopped by {sig.name}" in out
        assert "ingress delay" not in out or "ms" in out
        m = flow_metrics(str(trace))
        assert m["ca"].enqueued > 0


# -- plug-ins ----------------------------------------------------------------------------------------
PLUGINS = textwrap.dedent("""
    from uwsimnet_zenoh.mac import Mac
    from uwsimnet_zenoh.mac.nomac import NoMac

    class RaisesOnRx:
        def on_rx(self, rec):
            if rec["t"] > 2:
                raise RuntimeError("tracer bug")

    class ExitsOnRx:
        def on_rx(self, rec):
            raise SystemExit(0)

    class NoHandlers:
        pass

    class NeedsArgs:
        def __init__(self, x):
            pass
        def on_rx(self, rec):
            pass

    class BadMac(NoMac):
        n = 0
        def on_queue(self):
            BadMac.n += 1
            if BadMac.n > 20:
                raise ZeroDivisionError("mac bug")
            super().on_queue()
""")


@pytest.fixture
def plugins(tmp_path):
    (tmp_path / "edge_plugins.py").write_text(PLUGINS)
    (tmp_path / "edge_broken.py").write_text("raise ImportError('half installed')\n")
    return dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")


def _run(env, *args, timeout=120):
    return subprocess.run([*UWSIMNET, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)


def test_a_tracing_plugin_that_raises_is_reported_once_disabled_and_the_run_exits_2(tmp_path, plugins):
    sc = tmp_path / "s.xml"
    sc.write_text(scene(duration=30, tracing="<netTracingScript><className>edge_plugins:RaisesOnRx"
                                             "</className></netTracingScript>"))
    trace = tmp_path / "t.jsonl"
    r = _run(plugins, "run", str(sc), "--trace", str(trace))
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("RuntimeError: tracer bug") == 2          # the traceback's last line, the error line
    assert r.stderr.count("Traceback") == 1
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{sc}:4: tracing class edge_plugins:RaisesOnRx raised RuntimeError: tracer bug")
    assert "30 s simulated" in r.stdout                             # the run went on to its end
    a = analyse(trace, horizon=5.0)
    assert a.conservation.ok
    assert sum(m.delivered for m in a.flows.values()) > 0 and max(x["t"] for x in _records(trace)[1:]) > 20


def test_a_tracing_plugin_that_calls_exit_in_realtime_does_not_end_the_run_with_0(tmp_path, plugins):
    from test_broker_e2e import free_port

    port = free_port()
    sc = tmp_path / "s.xml"
    sc.write_text(scene(duration=2, clock="realtime", port=port,
                        tracing="<netTracingScript><className>edge_plugins:ExitsOnRx</className></netTracingScript>"))
    trace = tmp_path / "t.jsonl"
    r = _run(plugins, "run", str(sc), "--trace", str(trace), "--listen", f"tcp/127.0.0.1:{port}")
    assert r.returncode == 2, r.stderr
    assert "tracing class edge_plugins:ExitsOnRx raised SystemExit" in r.stderr
    recs = _records(trace)
    assert recs[-1]["ev"] == "end" and recs[-1]["reason"] == "duration" and recs[-1]["t"] == pytest.approx(2)
    rx = [x for x in recs if x["ev"] == "rx"]
    assert len(rx) > 1 and rx[-1]["t"] > rx[0]["t"]               # deliveries went on after it failed


def test_a_mac_plugin_that_raises_stops_the_run_with_exit_2_and_a_whole_trace(tmp_path, plugins):
    sc = tmp_path / "s.xml"
    sc.write_text(scene(duration=60, mac="<macProtocol><name>edge_plugins:BadMac</name></macProtocol>"))
    trace = tmp_path / "t.jsonl"
    r = _run(plugins, "run", str(sc), "--trace", str(trace))
    assert r.returncode == 2
    assert r.stderr.count("Traceback") == 1 and "ZeroDivisionError: mac bug" in r.stderr
    assert r.stderr.strip().splitlines()[-1].endswith("(traceback above; the trace ends there)")
    recs = _records(trace)
    assert recs[-1]["ev"] == "end" and recs[-1]["reason"] == "error"
    assert "ZeroDivisionError" in recs[-1]["error"]


@pytest.mark.parametrize("cls, needle", [
    ("edge_plugins:NoHandlers", "implements none of on_enq, on_tx, on_rx, on_drop"),
    ("edge_plugins:NeedsArgs", "could not be created: TypeError"),
    ("edge_plugins:Missing", "cannot load tracing class 'edge_plugins:Missing': AttributeError"),
    ("edge_broken:X", "cannot load tracing class 'edge_broken:X': ImportError: half installed"),
    ("edge_plugins:Mac", None),       # imported there, but a MAC base, not a tracing class
])
def test_tracing_plugins_are_checked_at_validate(tmp_path, plugins, cls, needle):
    sc = tmp_path / "s.xml"
    sc.write_text(scene(duration=10, tracing=f"<netTracingScript><className>{cls}</className></netTracingScript>"))
    r = _run(plugins, "validate", str(sc))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert r.stderr.startswith(f"{sc}:4: ")
    if needle:
        assert needle in r.stderr


def test_a_signal_stops_the_wait_and_never_deadlocks_it():
    """StopOnSignal (bus/router.py: `uwsimnet router`, realtime `uwsimnet run`): a signal that comes at any
    point of the main thread's wait ends it within the wait's slice, signum kept; a second one raises
    KeyboardInterrupt.  (Its handler once set a threading.Event: a signal inside that Event's wait
    deadlocked the process on the Event's lock, so a realtime run never ended.)"""
    import random
    import threading

    from uwsimnet_zenoh.bus.router import StopOnSignal

    assert threading.current_thread() is threading.main_thread()    # else SIGTERM would end this process
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    rnd = random.Random(7)
    for _ in range(200):
        with StopOnSignal() as stop:
            t = threading.Timer(rnd.uniform(0.0, 0.004), os.kill, (os.getpid(), signal.SIGTERM))
            t.start()
            t0 = time.monotonic()
            assert stop.wait(30.0)
            assert time.monotonic() - t0 < 5.0
            t.join()
            assert stop.stopped and stop.signum == signal.SIGTERM
    with StopOnSignal() as stop:
        assert not stop.wait(0.01) and not stop.stopped
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(5.0)
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
