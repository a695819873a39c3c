"""The lab walk-through of docs/deployment.md, followed literally: every role runs every command it is
documented to run, with its rendered configuration, over real routers (mutual TLS + usrpwd + the ACL
rendered from the one wire), and every action outside its role is refused, visibly.

Three hosts, one `uwsimnet router --config` each, in a chain h1 - h2 - h3 (h2 in the middle):

    h1  broker: `uwsimnet run --zenoh-config brk.json5`; visitor `vis`
    h2  modems host: `emu-z` (driver of z: `uwsimnet emulate serial`), `drv-y` (driver of y: `uwsimnet
        driver serial` on the emulated radio's pty)
    h3  robots: `app-a` (app, modem a, vehicle va), `app-b` (app, modems b y, vehicle vb: runs `uwsimnet
        vehicles`)

The hosts are three network namespaces of deploy/netns/hosts.sh where they can be made (root, `ip netns`,
`nsenter`), else loopback ports of their own (UWSIMNET_LAB_HOSTS=loopback|netns chooses).  Half-way
through, the middle router is restarted; the second half of the matrix runs on the restarted router.

Refusals are asserted two ways: the command exits 2 at once with one line naming the identity and the
key (it checks its rendered access section before opening a session: these run while h2 restarts); and
the routers themselves drop the same actions done with the raw Zenoh API (a put with the same
configuration reaches nobody, checked against a later allowed put on the same path).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

zenoh = pytest.importorskip("zenoh")

from conftest import netns_unavailable  # noqa: E402

from uwsimnet_zenoh.deploy import render as deploy  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MAKE_CERTS = ROOT / "deploy" / "tls" / "make-certs.sh"
HOSTS_SH = ROOT / "deploy" / "netns" / "hosts.sh"
UWSIMNET = [sys.executable, "-m", "uwsimnet_zenoh.cli"]
GLI = [sys.executable, "-m", "uwsimnet_gli.cli"]
WAIT = 20.0        # bound on every positive wait (seconds): a loaded 2-core machine
GRACE = 0.5        # extra time a forbidden message gets to show up after its positive control
WORLD = "lab"

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is not installed")

ZENOH_POSE = "<poseSource>zenoh</poseSource>"
SCENE = f"""<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>{WORLD}</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
""" + "".join(f"""  <vehicle><name>v{m}</name><position>{x} 0 0</position>{src}
    <CustomCommsDevice><dccommsId>{m}</dccommsId><mac>{mac}</mac><txChannelId>0</txChannelId>
      <rxChannelId>0</rxChannelId><bitrate>10000</bitrate></CustomCommsDevice></vehicle>
""" for m, mac, x, src in (("a", 1, 0, ZENOH_POSE), ("b", 2, 10, ZENOH_POSE), ("y", 3, 5, ""), ("z", 4, 6, "")))
SCENE += "</UWSimScene>\n"
ADDRESS = {"a": 1, "b": 2, "y": 3, "z": 4}

IDENTITIES = [
    {"name": "brk", "role": "broker", "host": "h1"},
    {"name": "vis", "role": "visitor", "host": "h1"},
    {"name": "ops", "role": "operator", "host": "h1"},
    {"name": "emu-z", "role": "driver", "host": "h2", "modems": ["z"]},
    {"name": "drv-y", "role": "driver", "host": "h2", "modems": ["y"]},
    {"name": "app-a", "role": "app", "host": "h3", "modems": ["a"], "vehicles": ["va"]},
    {"name": "app-b", "role": "app", "host": "h3", "modems": ["b", "y"], "vehicles": ["vb"]},
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_CONFIG"}
    env.update(PYTHONUNBUFFERED="1", RUST_LOG=os.environ.get("RUST_LOG", "error"))
    return env


class Proc:
    """A long-running command; `wait_for(text)` waits (bounded) for a line of its output."""

    def __init__(self, argv: list[str], name: str) -> None:
        self.name = name
        self.argv = argv
        self.lines: list[str] = []
        self.cond = threading.Condition()
        self.proc = subprocess.Popen(argv, cwd=ROOT, env=_env(), text=True, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self.cond:
                self.lines.append(line)
                self.cond.notify_all()
        with self.cond:
            self.cond.notify_all()

    def wait_for(self, text: str, timeout: float = WAIT) -> str:
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for line in self.lines:
                    if text in line:
                        return line
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise AssertionError(f"{self.name}: no {text!r} (exit {self.proc.poll()}):\n{self.output()}")
                self.cond.wait(min(left, 0.2))

    def output(self) -> str:
        with self.cond:
            return "".join(self.lines)

    def stop(self) -> int | None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        return self.proc.returncode


class Lab:
    """Certificates, rendered configurations, one router per host; commands run as an identity on its host."""

    def __init__(self, root: Path, addresses: dict[str, str], ports: dict[str, int],
                 exec_prefix: Callable[[str], list[str]]) -> None:
        self.root = root
        self.tls = root / "pki"
        self.out = root / "out"
        self.prefix = exec_prefix
        self.inventory = deploy.parse_inventory({
            "world": WORLD, "topology": "chain", "tls_dir": str(self.tls), "etc_dir": str(self.out / "{host}"),
            # on loopback, each router on a port of its own; in a namespace, every interface (the default)
            "hosts": {h: {"address": a, "port": ports[h]} | ({"listen": [f"tls/{a}:{ports[h]}"]} if a == "127.0.0.1"
                                                              else {}) for h, a in addresses.items()},
            "identities": IDENTITIES,
        }, "lab.toml")
        subprocess.run([str(MAKE_CERTS), str(self.tls), *deploy.cert_specs(self.inventory)], check=True,
                       capture_output=True, timeout=120)
        deploy.write(deploy.render(self.inventory), self.out)
        assert deploy.check(self.out) == []
        (root / "scene.xml").write_text(SCENE)
        self.routers: dict[str, Proc] = {}
        self.procs: list[Proc] = []

    def host(self, name: str) -> str:
        return self.inventory.identities[name].host if name in self.inventory.identities else name

    def config(self, name: str) -> Path:
        return self.out / self.host(name) / "clients" / f"{name}.json5"

    def start_router(self, host: str) -> None:
        p = Proc([*self.prefix(host), *UWSIMNET, "router", "--config", str(self.out / host / "router.json5")],
                 f"router {host}")
        p.wait_for("listening on")
        self.routers[host] = p

    def start(self, name: str, argv: list[str], ready: str, *, gli: bool = False) -> Proc:
        """A long-running command of identity `name` on its host, ready once `ready` is printed."""
        base = [*GLI, "--zenoh-config", str(self.config(name))] if gli else [*UWSIMNET]
        tail = [] if gli else ["--zenoh-config", str(self.config(name))]
        p = Proc([*self.prefix(self.host(name)), *base, *argv, *tail], f"{name}: {' '.join(argv)}")
        self.procs.append(p)
        p.wait_for(ready)
        return p

    def gli(self, name: str, *argv: str, timeout: float = WAIT) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*self.prefix(self.host(name)), *GLI, "--zenoh-config", str(self.config(name)),
                               *argv], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=timeout + 10)

    def uwsimnet(self, name: str, *argv: str, timeout: float = WAIT) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*self.prefix(self.host(name)), *UWSIMNET, *argv, "--zenoh-config",
                               str(self.config(name))], cwd=ROOT, env=_env(), capture_output=True, text=True,
                              timeout=timeout + 10)

    def python(self, host: str, code: str, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*self.prefix(host), sys.executable, "-c", code, *args], cwd=ROOT, env=_env(),
                              capture_output=True, text=True, timeout=WAIT + 10)

    def stop(self) -> None:
        for p in reversed(self.procs):
            p.stop()
        for p in self.routers.values():
            p.stop()
        logs = self.root / "logs"
        logs.mkdir(exist_ok=True)
        for i, p in enumerate([*self.procs, *self.routers.values()]):
            (logs / f"{i:02d}.log").write_text(f"{p.argv}\n{p.output()}")


def _loopback(tmp: Path) -> Iterator[Lab]:
    ports = {h: free_port() for h in ("h1", "h2", "h3")}
    yield Lab(tmp, dict.fromkeys(ports, "127.0.0.1"), ports, lambda host: [])


def _netns(tmp: Path) -> Iterator[Lab]:
    why = netns_unavailable("the lab matrix on emulated hosts", openssl=True)
    if why or shutil.which("nsenter") is None:
        pytest.skip(why or "needs nsenter (util-linux)")
    prefix = f"m{os.getpid() % 100000}"
    env = {**os.environ, "P": prefix, "NET": "10.79.0", "PY": sys.executable}
    r = subprocess.run([str(HOSTS_SH), "up", "3"], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    try:
        # nsenter execs the command itself (`ip netns exec` forks): signals reach the program
        yield Lab(tmp, {f"h{i}": f"10.79.0.{i}" for i in (1, 2, 3)}, dict.fromkeys(("h1", "h2", "h3"), 7447),
                  lambda host: ["nsenter", f"--net=/run/netns/{prefix}-{host}", "--"])
    finally:
        subprocess.run([str(HOSTS_SH), "down"], env=env, capture_output=True, timeout=60)


def hosts_kind() -> str:
    """netns where it works (root, iproute2, nsenter), else loopback; UWSIMNET_LAB_HOSTS=loopback|netns forces."""
    want = os.environ.get("UWSIMNET_LAB_HOSTS")
    if want:
        return want
    ok = netns_unavailable("the lab matrix", openssl=True) is None and shutil.which("nsenter") is not None
    return "netns" if ok else "loopback"


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Lab]:
    kind = hosts_kind()
    gen = (_loopback if kind == "loopback" else _netns)(tmp_path_factory.mktemp(f"lab-{kind}"))
    lab = next(gen)
    try:
        parallel(*(lambda h=h: lab.start_router(h) for h in ("h1", "h2", "h3")))
        yield lab
    finally:
        lab.stop()
        with contextlib.suppress(StopIteration):
            next(gen)


def ok(r: subprocess.CompletedProcess[str], *texts: str) -> str:
    assert r.returncode == 0, f"{r.args}\nstdout: {r.stdout}\nstderr: {r.stderr}"
    for t in texts:
        assert t in r.stdout + r.stderr, f"{r.args}: no {t!r}\nstdout: {r.stdout}\nstderr: {r.stderr}"
    return r.stdout


def refused(r: subprocess.CompletedProcess[str], who: str, what: str) -> None:
    """Exit 2, one line on stderr naming the identity and the refused key, nothing half-done."""
    assert r.returncode == 2, f"{r.args}\nstdout: {r.stdout}\nstderr: {r.stderr}"
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert who in lines[0] and what in lines[0] and "access control refuses" in lines[0], lines[0]


def info(lab: Lab, name: str, modem: str) -> dict[str, Any]:
    out = ok(lab.gli(name, "info", modem, "--json", "--timeout", "5"))
    (d,) = json.loads(out)
    return d


def info_when_routed(lab: Lab, name: str, modem: str) -> dict[str, Any]:
    """`info`, or {} while the broker's queryable has not reached this app's router yet (a declaration
    crosses the routers after the broker says it is running: the query then finds no queryable and gets no
    reply at once).  Any other failure fails."""
    r = lab.gli(name, "info", modem, "--json", "--timeout", "5")
    if r.returncode == 1 and r.stderr.strip() == f"no reply on 'uwsimnet/lab/modem/{modem}/info'":
        return {}
    (d,) = json.loads(ok(r))
    return d


def until(f: Callable[[], Any], what: str, timeout: float = WAIT) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        v = f()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what} (last: {v!r})")
        time.sleep(0.3)


def heard(listener: Proc, send: Callable[[], subprocess.CompletedProcess[str]]) -> subprocess.CompletedProcess[str]:
    """Send until the listener (`listen --count 1`) has heard the frame and exited 0; the last send's result.

    "Press CTRL-C" says the listener declared its subscriber, not that the declaration reached the broker's
    router two hops away: a frame delivered before that is routed nowhere, so the sender tries again (each
    try is a whole frame through the channel, several seconds apart) instead of sleeping a guessed second."""
    deadline = time.monotonic() + 3 * WAIT
    while True:
        r = send()
        try:
            assert listener.proc.wait(5.0) == 0, listener.output()
            return r
        except subprocess.TimeoutExpired:
            if time.monotonic() > deadline:
                raise AssertionError(f"listener heard nothing within {3 * WAIT} s: {listener.output()}") from None


def parallel(*calls: Callable[[], Any]) -> list[Any]:
    """Independent commands at once (each is a process): the matrix's wall time stays small."""
    out: list[Any] = [None] * len(calls)
    errs: list[BaseException] = []

    def run(i: int, f: Callable[[], Any]) -> None:
        try:
            out[i] = f()
        except BaseException as e:  # noqa: BLE001 - re-raised below
            errs.append(e)
    ts = [threading.Thread(target=run, args=(i, f)) for i, f in enumerate(calls)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    if errs:
        raise errs[0]
    return out


# == the matrix ========================================================================================

def test_lab_matrix(lab: Lab) -> None:
    t0 = time.monotonic()

    def phase(name: str) -> None:
        print(f"lab matrix: {name} at {time.monotonic() - t0:.1f} s", flush=True)
    # -- broker (h1), kinematic vehicles (app-b, h3), poses (app-a) ---------------------------------------
    lab.start("brk", ["run", str(lab.root / "scene.xml"), "--duration", "600", "--trace",
                      str(lab.root / "trace.jsonl")], "uwsimnet: running")
    lab.start("app-b", ["vehicles", "--vehicle", "vb=10,0,0", "--max-speed", "5"], "vehicles ready in lab: vb")

    def posed_va() -> bool:
        # a pose is a stream (a vehicle publishes its own at its rate): one put made before the broker's
        # subscription reached app-a's router is not routed anywhere, so app-a puts it again until it lands
        ok(lab.gli("app-a", "pose", "va", "0", "0", "0"))
        return info_when_routed(lab, "app-a", "a").get("position") == [0.0, 0.0, 0.0]
    # poses reach the broker (its pose/** subscriber): va where app-a put it, vb where `uwsimnet vehicles` is
    parallel(lambda: until(posed_va, "app-a's pose of va"),
             lambda: until(lambda: info_when_routed(lab, "app-b", "b").get("position") == [10.0, 0.0, 0.0],
                           "vb's pose from uwsimnet vehicles"))
    assert info(lab, "app-b", "b")["kind"] == "sim"

    phase("poses")
    # -- app: send --wait, listen, trace (visitor), control, vehicle commands ---------------------------
    listen_b, trace = parallel(
        lambda: lab.start("app-b", ["listen", "b", "--count", "1", "--timeout", str(WAIT), "--json"],
                          "Press CTRL-C", gli=True),
        lambda: lab.start("vis", ["trace", "--count", "1", "--timeout", str(WAIT)], "Declaring Subscriber", gli=True))
    sent = heard(listen_b, lambda: lab.gli("app-a", "send", "a", str(ADDRESS["b"]), "hello-b", "--wait",
                                           "--timeout", "10"))
    ok(sent, "(sim)")
    assert "  sent at" in sent.stdout or "  acked at" in sent.stdout, sent.stdout
    frame = json.loads(listen_b.wait_for('"modem": "b"'))
    assert frame["text"] == "hello-b" and frame["src"] == ADDRESS["a"]
    assert trace.proc.wait(WAIT) == 0, trace.output()
    assert json.loads(trace.wait_for('"ev"'))["ev"]
    state, _ = parallel(lambda: lab.gli("ops", "control", "state"),
                        lambda: ok(lab.gli("app-b", "vehicle", "vb", "waypoint=[20,0,0]")))
    assert json.loads(ok(state))["world"] == WORLD
    until(lambda: info(lab, "app-b", "b")["position"][0] > 10.5, "vb moving to its waypoint")

    phase("app")
    # -- refused: outside its role, at once and in one line ----------------------------------------
    checks = [
        (lambda: lab.gli("app-a", "send", "b", "1", "x", "--wait"), "app-a", "publish uwsimnet/lab/modem/b/tx"),
        (lambda: lab.gli("app-a", "info", "b"), "app-a", "query uwsimnet/lab/modem/b/info"),
        (lambda: lab.gli("app-a", "info"), "app-a", "query uwsimnet/lab/modem/*/info"),
        (lambda: lab.gli("app-a", "listen", "y"), "app-a", "subscribe uwsimnet/lab/modem/y/rx"),
        (lambda: lab.gli("app-a", "pose", "vb", "1", "1", "1"), "app-a", "publish uwsimnet/lab/pose/vb"),
        (lambda: lab.gli("app-a", "vehicle", "vb", "stop=true"), "app-a", "publish uwsimnet/lab/vehicle/vb/cmd"),
        (lambda: lab.gli("vis", "send", "a", "2", "x"), "vis", "publish uwsimnet/lab/modem/a/tx"),
        (lambda: lab.gli("vis", "info", "a"), "vis", "query uwsimnet/lab/modem/a/info"),
        (lambda: lab.gli("vis", "control", "pause"), "vis", "query uwsimnet/lab/control/*"),
        # #41: control is the operator's: an app may not pause, move another's vehicle, add or remove modems
        (lambda: lab.gli("app-a", "control", "pause"), "app-a", "query uwsimnet/lab/control/*"),
        (lambda: lab.gli("app-a", "control", "move", "vehicle=vb", "p=[0,0,0]"), "app-a",
         "query uwsimnet/lab/control/*"),
        (lambda: lab.gli("app-a", "control", "remove_device", "id=b"), "app-a", "query uwsimnet/lab/control/*"),
        (lambda: lab.gli("drv-y", "send", "y", "2", "x"), "drv-y", "watch uwsimnet/lab/modem/y/driver/*"),
        (lambda: lab.uwsimnet("app-a", "vehicles", "--vehicle", "vb=0,0,0"), "app-a",
         "publish uwsimnet/lab/pose/vb"),
        (lambda: lab.uwsimnet("app-a", "driver", "serial", "--device", "/dev/null", "--id", "a"), "app-a",
         "publish uwsimnet/lab/modem/a/rx"),
        (lambda: lab.uwsimnet("drv-y", "emulate", "serial", "--id", "z"), "drv-y", "publish uwsimnet/lab/modem/z/tx"),
        (lambda: lab.uwsimnet("vis", "bridge", "socket", "--id", "a"), "vis", "publish uwsimnet/lab/modem/a/tx"),
    ]
    # the routers drop the same actions done with the raw Zenoh API (before the restart: it needs h2)
    _router_refuses(lab)
    phase("raw refusals")

    # -- the middle router restarts; the second half runs on the new one ----------------------------
    def restart() -> None:
        lab.routers.pop("h2").stop()
        lab.start_router("h2")
        until(lambda: lab.gli("app-a", "info", "a", "--timeout", "2").returncode == 0,
              "app-a reaches the broker again")
    # meanwhile the refusals: checked by each command before it opens a session, they need no router
    results = parallel(restart, *(c for c, _, _ in checks))[1:]
    for r, (_, who, what) in zip(results, checks, strict=True):
        refused(r, who, what)

    phase("restart and refusals")
    # -- driver: an emulated serial radio (driver identity of z) and a real driver of y on its pty ----
    link = lab.root / "ttyRADIO"
    lab.start("emu-z", ["emulate", "serial", "--id", "z", "--link", str(link)], "emulator serial ready")
    lab.start("drv-y", ["driver", "serial", "--device", str(link), "--baud", "0", "--id", "y"],
              "driver serial ready for lab/y")
    _, listen_a = parallel(
        lambda: until(lambda: info(lab, "app-b", "y").get("kind") == "real", "y served by its real driver"),
        lambda: lab.start("app-a", ["listen", "a", "--count", "1", "--timeout", str(WAIT), "--json"],
                          "Press CTRL-C", gli=True))
    # app-b sends from y: its driver writes the frame to the radio (the emulated z), z transmits it to a
    ok(heard(listen_a, lambda: lab.gli("app-b", "send", "y", str(ADDRESS["a"]), "via-real-y", "--wait",
                                       "--timeout", "10")), "(real)")
    assert json.loads(listen_a.wait_for('"modem": "a"'))["text"] == "via-real-y"

    phase("driver")
    # -- a bridge with an app identity: a TCP application on modem a, frame to b --------------------
    listen_b, bridge = parallel(
        lambda: lab.start("app-b", ["listen", "b", "--count", "1", "--timeout", str(WAIT), "--json"],
                          "Press CTRL-C", gli=True),
        lambda: lab.start("app-a", ["bridge", "socket", "--id", "a"], "bridge socket ready"))
    port = int(bridge.wait_for("bridge socket ready").split("tcp 127.0.0.1:")[1].split()[0])
    r = heard(listen_b, lambda: lab.python(lab.host("app-a"), BRIDGE_CLIENT, str(port), str(ADDRESS["b"])))
    assert r.returncode == 0 and "sent" in r.stdout, r.stdout + r.stderr
    assert json.loads(listen_b.wait_for('"modem": "b"'))["text"] == "bridged"
    print(f"lab matrix: {time.monotonic() - t0:.1f} s")


BRIDGE_CLIENT = """
import sys
from uwsimnet_zenoh.bridges.socket_client import SocketBridgeClient
c = SocketBridgeClient("127.0.0.1", int(sys.argv[1]))
c.send(int(sys.argv[2]), b"bridged", 7)
st = c.wait_status(7, "sent", timeout=10)
print(c.address, st and st.event)
"""

ROUTER_REFUSES = """
import json, sys, threading, time, zenoh
from uwsimnet_gli import wire
conf = dict(zip(("app-a", "vis", "app-b"), sys.argv[1:])).get
got = []
cond = threading.Condition()
def cb(s):
    with cond:
        got.append((str(s.key_expr), s.payload.to_bytes()))
        cond.notify_all()
def wait(pred, t):
    end = time.monotonic() + t
    with cond:
        while not any(pred(g) for g in got) and time.monotonic() < end:
            cond.wait(0.1)
        return any(pred(g) for g in got)
def session(name):
    return zenoh.open(zenoh.Config.from_file(conf(name)))
with session("app-a") as a, session("vis") as v, session("app-b") as b:
    sub = b.declare_subscriber("uwsimnet/lab/modem/b/status", cb)
    tag = lambda s: wire.decode_status(s[1]).tag
    def control(t):
        for _ in range(40):
            b.put("uwsimnet/lab/modem/b/tx", wire.encode_tx(1, b"control", t))
            if wait(lambda s: tag(s) == t, 0.5):
                return True
        return False
    ready = control(100)            # b's status subscription is in place: a forged frame's status would come
    # forged: app-a on modem b, the visitor on modem b; then app-b's own tx (allowed) on the same path
    a.put("uwsimnet/lab/modem/b/tx", wire.encode_tx(1, b"forged", 101))
    v.put("uwsimnet/lab/modem/b/tx", wire.encode_tx(1, b"forged", 102))
    v.put("uwsimnet/lab/pose/vb", wire.encode_pose([99, 99, 99]))
    a.put("uwsimnet/lab/pose/vb", wire.encode_pose([98, 98, 98]))
    time.sleep(0.5)                 # (a forged frame that got through would be answered within this)
    ok = ready and control(103)
    time.sleep(0.5)
    print(json.dumps({"control": ok, "forged": sorted({tag(s) for s in got} & {101, 102})}))
"""


def _router_refuses(lab: Lab) -> None:
    """Run on the apps' host: app-a and app-b log in to their router, the visitor to the router its file
    names (the same ACL and users everywhere)."""
    r = lab.python(lab.host("app-a"), ROUTER_REFUSES, *(str(lab.config(n)) for n in ("app-a", "vis", "app-b")))
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res == {"control": True, "forged": []}, res
    # the forged poses of vb moved nothing
    assert info(lab, "app-b", "b")["position"][0] < 90
