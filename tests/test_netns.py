"""Emulated hosts (deploy/netns/hosts.sh): three network namespaces on a bridge, one router in each,
routers connected over mutual TLS with the generated configurations, a publisher in host 1 and a
subscriber in host 3.  Needs root and `ip netns`; the namespaces are always removed."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import netns_unavailable

ROOT = Path(__file__).resolve().parents[1]
HOSTS = ROOT / "deploy" / "netns" / "hosts.sh"
PUBSUB = ROOT / "deploy" / "netns" / "pubsub.py"


WHY_NOT = netns_unavailable("the multi-host test", openssl=True)
pytestmark = pytest.mark.skipif(WHY_NOT is not None, reason=WHY_NOT or "")


def _namespaces(prefix: str) -> list[str]:
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    return [ln.split()[0] for ln in out.splitlines() if ln.split() and ln.split()[0].startswith(f"{prefix}-")]


class Hosts:
    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self.env = {**os.environ, "P": prefix, "PY": sys.executable, "TIMEOUT": "15"}

    def run(self, *args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        r = subprocess.run([str(HOSTS), *args], env=self.env, capture_output=True, text=True, timeout=timeout,
                           cwd=ROOT)
        assert r.returncode == 0, f"hosts.sh {' '.join(args)}: {r.stdout}{r.stderr}"
        return r


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    h = Hosts(f"t{os.getpid() % 1000000}")
    try:
        yield h
    finally:
        subprocess.run([str(HOSTS), "down"], env=h.env, capture_output=True, timeout=60)
        assert _namespaces(h.prefix) == []


def test_pubsub_across_three_hosts(hosts: Hosts, tmp_path: Path) -> None:
    from uwsimnet_zenoh.deploy import render as deploy

    hosts.run("up", "3")
    assert sorted(_namespaces(hosts.prefix)) == sorted(f"{hosts.prefix}-{n}" for n in ("sw", "h1", "h2", "h3"))
    # the addresses live inside the namespaces only
    assert "10.77.0." not in subprocess.run(["ip", "-4", "addr"], capture_output=True, text=True).stdout
    inv = deploy.parse_inventory({
        "world": "lab", "topology": "star", "hub": "h2",
        "tls_dir": str(tmp_path / "tls"), "etc_dir": str(tmp_path / "out" / "{host}"),
        "hosts": {f"h{i}": {"address": f"10.77.0.{i}", "listen": ["tls/0.0.0.0:7447"]} for i in (1, 2, 3)},
        "identities": [{"name": "pub", "role": "app", "host": "h1"},
                       {"name": "sub", "role": "app", "host": "h3"}],
    }, "netns-inventory")
    subprocess.run([str(ROOT / "deploy" / "tls" / "make-certs.sh"), str(tmp_path / "tls"),
                    *deploy.cert_specs(inv)], check=True, capture_output=True, timeout=60)
    out = tmp_path / "out"
    deploy.write(deploy.render(inv), out)
    try:
        started = hosts.run("routers", str(out)).stdout
        assert started.count("listening on") == 3, started
        key = "uwsimnet/lab/pose/auv1"
        sub_out = tmp_path / "sub.out"
        with open(sub_out, "w") as fh:
            sub = subprocess.Popen([str(HOSTS), "exec", "3", sys.executable, str(PUBSUB), "sub",
                                    str(out / "h3" / "clients" / "sub.json5"), key, "3"],
                                   env=hosts.env, stdout=fh, stderr=subprocess.STDOUT, cwd=ROOT)
            try:
                hosts.run("exec", "1", sys.executable, str(PUBSUB), "pub", str(out / "h1" / "clients" / "pub.json5"),
                          key, "3", str(sub_out))
                assert sub.wait(timeout=30) == 0, sub_out.read_text()
            finally:
                if sub.poll() is None:
                    sub.kill()
                    sub.wait(timeout=10)
        got = [ln for ln in sub_out.read_text().splitlines() if ln.startswith("got ")]
        assert sorted(g.split()[2] for g in got) == ["0", "1", "2"], sub_out.read_text()
    finally:
        hosts.run("stop-routers", str(out))
        for h in ("h1", "h2", "h3"):
            log = out / h / "router.log"
            if log.exists():
                print(h, log.read_text())


def test_demo_runs_and_cleans_up(hosts: Hosts) -> None:
    r = hosts.run("demo", "3", timeout=120)
    assert "demo: ok" in r.stdout
    assert _namespaces(hosts.prefix) == []


def test_down_is_idempotent(hosts: Hosts) -> None:
    hosts.run("up", "2")
    hosts.run("down")
    hosts.run("down")
    assert _namespaces(hosts.prefix) == []


def test_failed_up_cleans_up(hosts: Hosts) -> None:
    r = subprocess.run([str(HOSTS), "up", "2"], env={**hosts.env, "NET": "999.1.1"}, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode != 0 and "cleaning up" in r.stderr
    assert _namespaces(hosts.prefix) == []
