"""TLS, user/password authentication and access control, with real routers (docs/deployment.md).

Two routers (hosts `hb` and `hr`, both on loopback) run in subprocesses with the configurations that
`uwsimnet_zenoh.deploy.render` renders from an inventory, and certificates from deploy/tls/make-certs.sh:
`hb` through `uwsimnet router --config`, `hr` through a bare `zenoh.open(Config.from_file(...))`.
Clients (broker, driver, app, visitor) are sessions in this process, on either router: every sample
between them crosses mutual TLS and the ACL of both routers.

Refusals are asserted the way Zenoh 1.10 shows them: a client that fails authentication cannot open
its session (`zenoh.open` raises ZError); a client that is authenticated but not allowed is not
disconnected, its messages are silently dropped by its router.  "Never arrives" is checked against
a positive control sent after the forbidden message on the same path, then a short grace period.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
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

from uwsimnet_zenoh.deploy import render as deploy  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MAKE_CERTS = ROOT / "deploy" / "tls" / "make-certs.sh"
WAIT = 10.0       # bound on every positive wait (seconds)
GRACE = 0.5       # extra time a forbidden message gets to show up after its positive control
REFUSE_MS = 300   # connect timeout of clients expected to be refused

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is not installed")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Router:
    """A router subprocess; `ready` waits (bounded) for its first line of output."""

    def __init__(self, argv: list[str], log: Path, ready_text: str) -> None:
        self.log = log
        self.lines: queue.Queue[str] = queue.Queue()
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     stdin=subprocess.DEVNULL, cwd=ROOT,
                                     env={**os.environ, "RUST_LOG": os.environ.get("RUST_LOG", "error")})
        self.output: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()
        deadline = time.monotonic() + WAIT
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                self.stop()
                raise AssertionError(f"router {argv} not ready after {WAIT} s: {self.output}") from None
            if ready_text in line:
                return
            if self.proc.poll() is not None and self.lines.empty():
                raise AssertionError(f"router {argv} exited {self.proc.returncode}: {self.output}")

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.output.append(line)
            self.lines.put(line)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        self.log.write_text("".join(self.output))


LAUNCHER = """
import signal, sys, threading, zenoh
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: stop.set())
with zenoh.open(zenoh.Config.from_file(sys.argv[1])) as s:
    print("ready", s.zid(), flush=True)
    stop.wait()
"""


class Deployment:
    def __init__(self, root: Path) -> None:
        self.root = root
        self.tls = root / "tls"
        self.out = root / "out"
        self.ports = {"hb": free_port(), "hr": free_port()}
        self.inventory = deploy.parse_inventory({
            "world": "w",
            "tls_dir": str(self.tls),
            "etc_dir": str(self.out / "{host}"),
            "hosts": {h: {"address": "127.0.0.1", "port": p, "listen": [f"tls/127.0.0.1:{p}"]}
                      for h, p in self.ports.items()},
            "identities": [
                {"name": "brk", "role": "broker", "host": "hb"},
                {"name": "vis", "role": "visitor", "host": "hb"},
                {"name": "app", "role": "app", "host": "hr"},
                {"name": "drv", "role": "driver", "host": "hr", "modems": ["y"]},
            ],
        }, "test-inventory")
        specs = deploy.cert_specs(self.inventory)
        subprocess.run([str(MAKE_CERTS), str(self.tls), *specs], check=True, capture_output=True, timeout=60)
        # a certificate with a valid name from a CA nobody trusts
        subprocess.run([str(MAKE_CERTS), str(root / "rogue"), "app"], check=True, capture_output=True,
                       timeout=60)
        self.files = deploy.render(self.inventory)
        deploy.write(self.files, self.out)
        self.passwords = deploy.parse_passwords(self.files["passwords.txt"])
        self.routers: list[Router] = []

    def start(self) -> None:
        hb, hr = self.out / "hb" / "router.json5", self.out / "hr" / "router.json5"
        # `uwsimnet router --config` listens on the file's endpoints (TLS only here): no --listen needed
        self.routers.append(Router([sys.executable, "-m", "uwsimnet_zenoh.cli", "router", "--config", str(hb)],
                                   self.root / "hb.log", "listening on"))
        self.routers.append(Router([sys.executable, "-c", LAUNCHER, str(hr)], self.root / "hr.log", "ready"))

    def stop(self) -> None:
        for r in self.routers:
            r.stop()

    def config(self, name: str, edit: Callable[[dict[str, Any]], None] | None = None,
               timeout_ms: int | None = None) -> zenoh.Config:
        """The rendered client configuration of `name`, optionally edited (to forge bad credentials)."""
        path = self.out / self.inventory.identities[name].host / "clients" / f"{name}.json5"
        conf = zenoh.Config.from_file(str(path))
        if edit is not None:
            d: dict[str, Any] = {}
            edit(d)
            for k, v in d.items():
                conf.insert_json5(k, json.dumps(v))
        if timeout_ms is not None:
            conf.insert_json5("connect/timeout_ms", str(timeout_ms))
        return conf


@pytest.fixture(scope="module")
def dep(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    d = Deployment(tmp_path_factory.mktemp("security"))
    try:
        d.start()
        yield d
    finally:
        d.stop()


@contextlib.contextmanager
def session(d: Deployment, name: str) -> Iterator[zenoh.Session]:
    with zenoh.open(d.config(name, timeout_ms=int(WAIT * 1000))) as s:
        yield s


class Inbox:
    """Samples received by callbacks, with bounded waits."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str, str]] = []
        self.cond = threading.Condition()

    def cb(self, tag: str) -> Callable[[Any], None]:
        def f(sample: Any) -> None:
            with self.cond:
                self.items.append((tag, str(sample.key_expr), sample.payload.to_string()))
                self.cond.notify_all()
        return f

    def live(self, tag: str) -> Callable[[Any], None]:
        def f(sample: Any) -> None:
            with self.cond:
                self.items.append((tag, str(sample.key_expr), str(sample.kind).rsplit(".", 1)[-1]))
                self.cond.notify_all()
        return f

    def wait_for(self, pred: Callable[[tuple[str, str, str]], bool], timeout: float = WAIT) -> bool:
        deadline = time.monotonic() + timeout
        with self.cond:
            while not any(pred(i) for i in self.items):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(left)
            return True

    def seen(self, pred: Callable[[tuple[str, str, str]], bool]) -> bool:
        with self.cond:
            return any(pred(i) for i in self.items)


def until_delivered(pub: Callable[[], None], inbox: Inbox, pred: Callable[[tuple[str, str, str]], bool]) -> None:
    """Publish (again every 0.2 s) until the inbox has a matching sample: subscriptions take a moment to
    reach the other router.  Bounded by WAIT."""
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        pub()
        if inbox.wait_for(pred, 0.2):
            return
    raise AssertionError(f"never delivered; inbox: {inbox.items}")


# -- authentication --------------------------------------------------------------------------------

def test_rendered_configs_load_in_zenoh(dep: Deployment) -> None:
    assert deploy.check(dep.out) == []
    router = json.loads(zenoh.Config.from_file(str(dep.out / "hb" / "router.json5")).__str__())
    tls = router["transport"]["link"]["tls"]
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert router["access_control"]["enabled"] is True
    assert router["access_control"]["default_permission"] == "deny"
    assert router["transport"]["auth"]["usrpwd"]["dictionary_file"].endswith("hb/users.txt")
    assert oct((dep.out / "hb" / "users.txt").stat().st_mode & 0o777) == "0o600"


def test_authenticated_client_opens(dep: Deployment) -> None:
    with session(dep, "app") as s:
        assert len(list(s.info.routers_zid())) == 1


def _refused(conf: zenoh.Config) -> str:
    t = time.monotonic()
    with pytest.raises(zenoh.ZError) as e, zenoh.open(conf):
        pass
    assert time.monotonic() - t < WAIT
    return str(e.value)


def test_client_without_credentials_is_refused(dep: Deployment) -> None:
    def no_user(d: dict[str, Any]) -> None:
        d["transport/auth/usrpwd"] = {"user": None, "password": None, "dictionary_file": None}
    _refused(dep.config("app", no_user, timeout_ms=REFUSE_MS))


def test_wrong_password_is_refused(dep: Deployment) -> None:
    def bad(d: dict[str, Any]) -> None:
        d["transport/auth/usrpwd/password"] = dep.passwords["app"] + "x"
    _refused(dep.config("app", bad, timeout_ms=REFUSE_MS))


def test_another_identitys_password_is_refused(dep: Deployment) -> None:
    def swapped(d: dict[str, Any]) -> None:
        d["transport/auth/usrpwd/password"] = dep.passwords["vis"]
    _refused(dep.config("app", swapped, timeout_ms=REFUSE_MS))


def test_client_without_certificate_is_refused(dep: Deployment) -> None:
    def no_cert(d: dict[str, Any]) -> None:
        d["transport/link/tls/enable_mtls"] = False
        d["transport/link/tls/connect_certificate"] = None
        d["transport/link/tls/connect_private_key"] = None
    _refused(dep.config("app", no_cert, timeout_ms=REFUSE_MS))


def test_certificate_from_another_ca_is_refused(dep: Deployment) -> None:
    def rogue(d: dict[str, Any]) -> None:
        d["transport/link/tls/connect_certificate"] = str(dep.root / "rogue" / "app.pem")
        d["transport/link/tls/connect_private_key"] = str(dep.root / "rogue" / "app.key")
    _refused(dep.config("app", rogue, timeout_ms=REFUSE_MS))


def test_client_that_does_not_trust_the_router_is_refused(dep: Deployment) -> None:
    def other_ca(d: dict[str, Any]) -> None:
        d["transport/link/tls/root_ca_certificate"] = str(dep.root / "rogue" / "ca.pem")
    _refused(dep.config("app", other_ca, timeout_ms=REFUSE_MS))


def test_plain_tcp_is_refused(dep: Deployment) -> None:
    def tcp(d: dict[str, Any]) -> None:
        d["transport/link/protocols"] = ["tcp"]
        d["connect/endpoints"] = [f"tcp/127.0.0.1:{dep.ports['hr']}"]
    _refused(dep.config("app", tcp, timeout_ms=REFUSE_MS))


# -- access control --------------------------------------------------------------------------------

def test_visitor_reads_traces_but_cannot_publish_rx(dep: Deployment) -> None:
    inbox = Inbox()
    with session(dep, "brk") as brk, session(dep, "vis") as vis, session(dep, "app") as app, \
            session(dep, "vis") as vis_broad:
        subs = [vis.declare_subscriber("uwsimnet/w/trace/*", inbox.cb("vis-trace")),
                # broader than allowed: refused by the router as a whole, so it gets not even traces
                vis_broad.declare_subscriber("uwsimnet/**", inbox.cb("vis-broad")),
                vis.declare_subscriber("uwsimnet/w/modem/*/rx", inbox.cb("vis-rx")),
                app.declare_subscriber("uwsimnet/w/modem/x/rx", inbox.cb("app-rx")),
                brk.declare_subscriber("uwsimnet/w/modem/*/rx", inbox.cb("brk-rx"))]
        until_delivered(lambda: brk.put("uwsimnet/w/trace/0", "trace"), inbox,
                        lambda i: i[0] == "vis-trace" and i[2] == "trace")
        # the broker's rx reaches the app on the other router, never the visitor (not even by wildcard)
        until_delivered(lambda: brk.put("uwsimnet/w/modem/x/rx", "from-broker"), inbox,
                        lambda i: i[0] == "app-rx" and i[2] == "from-broker")
        # the visitor forges an rx; then the broker puts one more (positive control, later in time)
        vis.put("uwsimnet/w/modem/x/rx", "forged")
        vis.put("uwsimnet/w/trace/0", "forged-trace")
        time.sleep(GRACE)
        brk.put("uwsimnet/w/modem/x/rx", "control")
        assert inbox.wait_for(lambda i: i[0] == "app-rx" and i[2] == "control")
        time.sleep(GRACE)
        assert not inbox.seen(lambda i: i[0] == "app-rx" and i[2] == "forged"), inbox.items
        assert not inbox.seen(lambda i: i[0] == "brk-rx" and i[2].startswith("forged")), inbox.items
        assert not inbox.seen(lambda i: i[0] == "vis-rx" and i[2] != "forged"), inbox.items  # only its own
        assert not inbox.seen(lambda i: i[0] == "vis-broad"), inbox.items
        # and a visitor's queries reach nobody
        served = []

        def info(q: Any) -> None:
            served.append(str(q.key_expr))
            with q:
                q.reply("uwsimnet/w/modem/x/info", "info")
        qable = brk.declare_queryable("uwsimnet/w/modem/*/info", info)
        assert _eventually(lambda: [r for r in app.get("uwsimnet/w/modem/x/info", timeout=1) if r.ok])
        n_served = len(served)
        assert [r for r in vis.get("uwsimnet/w/modem/x/info", timeout=GRACE) if r.ok] == []
        assert len(served) == n_served
        del subs, qable


def _eventually(f: Callable[[], Any]) -> Any:
    deadline = time.monotonic() + WAIT
    while True:
        v = f()
        if v or time.monotonic() > deadline:
            return v
        time.sleep(0.1)


def test_app_puts_tx_but_cannot_claim_a_modem(dep: Deployment) -> None:
    inbox = Inbox()
    with session(dep, "brk") as brk, session(dep, "app") as app, session(dep, "drv") as drv:
        subs = [brk.declare_subscriber("uwsimnet/w/modem/*/tx", inbox.cb("brk-tx")),
                brk.declare_subscriber("uwsimnet/w/modem/*/rx", inbox.cb("brk-rx")),
                brk.liveliness().declare_subscriber("uwsimnet/w/modem/*/driver/real", inbox.live("brk-live"),
                                                    history=True)]
        # a declared publisher (as uwsimnet_gli uses) and a plain put both reach the broker
        pub = app.declare_publisher("uwsimnet/w/modem/x/tx")
        until_delivered(lambda: pub.put("via-publisher"), inbox, lambda i: i[0] == "brk-tx" and i[2] == "via-publisher")
        app.put("uwsimnet/w/modem/x/tx", "via-put")
        assert inbox.wait_for(lambda i: i[0] == "brk-tx" and i[2] == "via-put")
        # the app forges an rx and a driver/real token: after a later tx from the same session has
        # arrived (same path, in order), neither has
        app.put("uwsimnet/w/modem/x/rx", "forged")
        forged_token = app.liveliness().declare_token("uwsimnet/w/modem/x/driver/real")
        time.sleep(GRACE)
        app.put("uwsimnet/w/modem/x/tx", "control")
        assert inbox.wait_for(lambda i: i[0] == "brk-tx" and i[2] == "control")
        # the driver (restricted to modem y) declares its token: the broker sees it
        real = drv.liveliness().declare_token("uwsimnet/w/modem/y/driver/real")
        assert inbox.wait_for(lambda i: i == ("brk-live", "uwsimnet/w/modem/y/driver/real", "PUT")), inbox.items
        time.sleep(GRACE)
        assert not inbox.seen(lambda i: i[1] == "uwsimnet/w/modem/x/driver/real"), inbox.items
        assert not inbox.seen(lambda i: i[0] == "brk-rx"), inbox.items
        del real
        assert inbox.wait_for(lambda i: i == ("brk-live", "uwsimnet/w/modem/y/driver/real", "DELETE"))
        del forged_token, subs


def test_driver_is_limited_to_its_modems(dep: Deployment) -> None:
    inbox = Inbox()
    with session(dep, "drv") as drv, session(dep, "app") as app, session(dep, "brk") as brk:
        subs = [app.declare_subscriber("uwsimnet/w/modem/*/rx", inbox.cb("app-rx")),
                brk.liveliness().declare_subscriber("uwsimnet/w/modem/*/driver/real", inbox.live("brk-live"),
                                                    history=True)]
        wrong = drv.liveliness().declare_token("uwsimnet/w/modem/x/driver/real")  # not its modem
        drv.put("uwsimnet/w/modem/x/rx", "forged")
        time.sleep(GRACE)
        until_delivered(lambda: drv.put("uwsimnet/w/modem/y/rx", "real-rx"), inbox,
                        lambda i: i[0] == "app-rx" and i[2] == "real-rx")
        right = drv.liveliness().declare_token("uwsimnet/w/modem/y/driver/real")
        assert inbox.wait_for(lambda i: i == ("brk-live", "uwsimnet/w/modem/y/driver/real", "PUT"))
        time.sleep(GRACE)
        assert not inbox.seen(lambda i: i[2] == "forged"), inbox.items
        assert not inbox.seen(lambda i: "modem/x/driver" in i[1]), inbox.items
        del wrong, right, subs


def test_authenticated_user_with_someone_elses_certificate_gets_nothing(dep: Deployment) -> None:
    """User name and certificate CN must belong to the same group: the app's password with the
    visitor's certificate authenticates (both are valid) but matches no ACL subject: default deny."""
    inbox = Inbox()

    def vis_cert(d: dict[str, Any]) -> None:
        d["transport/link/tls/connect_certificate"] = str(dep.tls / "vis.pem")
        d["transport/link/tls/connect_private_key"] = str(dep.tls / "vis.key")
    with session(dep, "brk") as brk, zenoh.open(dep.config("app", vis_cert, timeout_ms=int(WAIT * 1000))) as mixed, \
            session(dep, "app") as app:
        subs = [brk.declare_subscriber("uwsimnet/w/modem/*/tx", inbox.cb("brk-tx")),
                mixed.declare_subscriber("uwsimnet/w/trace/**", inbox.cb("mixed-trace"))]
        mixed.put("uwsimnet/w/modem/x/tx", "mixed")
        time.sleep(GRACE)
        until_delivered(lambda: app.put("uwsimnet/w/modem/x/tx", "app"), inbox,
                        lambda i: i[0] == "brk-tx" and i[2] == "app")
        brk.put("uwsimnet/w/trace/0", "trace")
        time.sleep(GRACE)
        assert not inbox.seen(lambda i: i[2] == "mixed" or i[0] == "mixed-trace"), inbox.items
        del subs


SCENE = """<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>w</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  <vehicle><name>vx</name><position>0 0 0</position><CustomCommsDevice><dccommsId>x</dccommsId><mac>1</mac>
    <txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate></CustomCommsDevice></vehicle>
  <vehicle><name>vy</name><position>100 0 0</position><CustomCommsDevice><dccommsId>y</dccommsId><mac>2</mac>
    <txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate></CustomCommsDevice></vehicle>
</UWSimScene>
"""


def test_run_and_gli_log_in_with_client_configs(dep: Deployment, tmp_path: Path) -> None:
    """`uwsimnet run` as the broker identity (ZENOH_CONFIG, no --connect: the file's endpoint) on hb;
    `gli --zenoh-config` as the app identity on hr: a frame crosses TLS, usrpwd and both ACLs."""
    scene = tmp_path / "w.xml"
    scene.write_text(SCENE)
    brk = dep.out / "hb" / "clients" / "brk.json5"
    app = str(dep.out / "hr" / "clients" / "app.json5")
    env = {**os.environ, "ZENOH_CONFIG": str(brk), "PYTHONUNBUFFERED": "1", "RUST_LOG": "error"}
    run = subprocess.Popen([sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(scene), "--duration", "60",
                            "--trace", str(tmp_path / "t.jsonl")], cwd=ROOT, env=env, text=True,
                           stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    out: list[str] = []
    threading.Thread(target=lambda: out.extend(run.stdout or ()), daemon=True).start()
    gli = [sys.executable, "-m", "uwsimnet_gli.cli", "--zenoh-config", app, "-w", "w"]
    genv = {k: v for k, v in os.environ.items() if k != "ZENOH_CONFIG"}
    try:
        deadline = time.monotonic() + WAIT
        while not any("uwsimnet: running" in line for line in out):
            assert run.poll() is None and time.monotonic() < deadline, "".join(out)
            time.sleep(0.05)
        assert any("connected to tls/127.0.0.1" in line for line in out), "".join(out)
        listen = subprocess.Popen([*gli, "listen", "y", "--count", "1", "--timeout", str(WAIT), "--json"],
                                  cwd=ROOT, env=genv, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            # "Press CTRL-C" is not yet a route from the broker: a frame delivered before the subscription
            # reached it goes nowhere, so send again until the listener (--count 1) has one
            for _ in range(4):
                send = subprocess.run([*gli, "send", "x", "2", "hello", "--wait"], cwd=ROOT, env=genv,
                                      capture_output=True, text=True, timeout=WAIT + 10)
                assert send.returncode == 0, send.stdout + send.stderr
                try:
                    listen.wait(timeout=5)
                    break
                except subprocess.TimeoutExpired:
                    continue
            lo, le = listen.communicate(timeout=WAIT + 5)
        finally:
            if listen.poll() is None:
                listen.kill()
                listen.wait(5)
        frames = [json.loads(line) for line in lo.splitlines() if line.startswith("{")]
        assert len(frames) == 1 and bytes.fromhex(frames[0]["data_hex"]) == b"hello", lo + le
    finally:
        if run.poll() is None:
            run.terminate()
        try:
            run.wait(timeout=15)
        except subprocess.TimeoutExpired:
            run.kill()
            run.wait(5)
        (tmp_path / "run.log").write_text("".join(out))
