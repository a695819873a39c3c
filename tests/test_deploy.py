"""The deployment generator: inventory checks, topologies, roles -> ACL, rendered files (no network)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from uwsimnet_zenoh.cli import main as cli_main
from uwsimnet_zenoh.deploy import render as deploy

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "deploy" / "inventory.example.toml"


def inv(**over: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "hosts": {"broker": {"address": "10.77.0.1"}, "robot1": {"address": "10.77.0.2"},
                  "robot2": {"address": "10.77.0.3"}},
        "identities": [{"name": "sim", "role": "broker", "host": "broker"},
                       {"name": "app1", "role": "app", "host": "robot1", "modems": ["m1"]},
                       {"name": "s2c", "role": "driver", "host": "robot2"},
                       {"name": "guest", "role": "visitor", "host": "laptop", "router": "broker"}],
    }
    d.update(over)
    return d


def test_example_inventory_renders_and_loads_in_zenoh(tmp_path: Path) -> None:
    zenoh = pytest.importorskip("zenoh")
    files = deploy.render(deploy.load_inventory(EXAMPLE))
    deploy.write(files, tmp_path)
    assert deploy.check(tmp_path) == []
    for rel in files:
        if rel.endswith(".json5"):
            zenoh.Config.from_file(str(tmp_path / rel))  # unknown keys would raise
    assert all((tmp_path / rel).stat().st_mode & 0o077 == 0 for rel in files)


def test_files_per_host() -> None:
    files = deploy.render(inv(), {"sim": "a"})
    assert set(files) == {
        "passwords.txt",
        "broker/router.json5", "broker/users.txt", "robot1/router.json5", "robot1/users.txt",
        "robot2/router.json5", "robot2/users.txt", "broker/router.env", "robot1/router.env", "robot2/router.env",
        "broker/clients/sim.json5", "robot1/clients/app1.json5", "robot2/clients/s2c.json5",
        "laptop/clients/guest.json5", "broker/broker-sim.env",
    }
    assert files["robot1/router.env"].endswith("ROUTER_ARGS=--listen=tls/[::]:7447\n")
    env = files["broker/broker-sim.env"]
    assert "ZENOH_CONFIG=/etc/uwsimnet/broker/clients/sim.json5\n" in env
    assert "CONNECT=tls/127.0.0.1:7447\n" in env
    users = deploy.parse_passwords(files["passwords.txt"])
    assert set(users) == {"broker", "robot1", "robot2", "sim", "app1", "s2c", "guest"}
    assert users["sim"] == "a"                       # given passwords are kept
    assert files["broker/users.txt"] == files["passwords.txt"]


def test_router_and_client_configs() -> None:
    i = deploy.parse_inventory(inv())
    pw = deploy.make_passwords(i)
    r = deploy.router_config(i, "robot1", pw)
    assert r["mode"] == "router"
    assert r["listen"]["endpoints"] == ["tls/[::]:7447"]
    assert r["connect"]["endpoints"] == ["tls/10.77.0.1:7447"]          # star around the first host
    assert r["transport"]["link"]["tls"]["listen_certificate"] == "/etc/uwsimnet/tls/robot1.pem"
    assert r["transport"]["auth"]["usrpwd"]["user"] == "robot1"
    assert r["transport"]["auth"]["usrpwd"]["dictionary_file"] == "/etc/uwsimnet/robot1/users.txt"
    local = deploy.client_config(i, "app1", pw)
    assert local["connect"]["endpoints"] == ["tls/127.0.0.1:7447"]     # its own machine's router
    remote = deploy.client_config(i, "guest", pw)
    assert remote["connect"]["endpoints"] == ["tls/10.77.0.1:7447"]    # a machine without a router
    assert remote["transport"]["link"]["tls"]["connect_certificate"] == "/etc/uwsimnet/tls/guest.pem"
    assert remote["transport"]["link"]["tls"]["enable_mtls"] is True
    assert remote["transport"]["auth"]["usrpwd"] == {"user": "guest", "password": pw["guest"]}


@pytest.mark.parametrize(("topology", "links"), [
    ("star", {"a": (), "b": ("a",), "c": ("a",)}),
    ("chain", {"a": (), "b": ("a",), "c": ("b",)}),
    ("mesh", {"a": (), "b": ("a",), "c": ("a", "b")}),
])
def test_topologies(topology: str, links: dict[str, tuple[str, ...]]) -> None:
    i = deploy.parse_inventory({"topology": topology, "identities": [],
                                "hosts": {h: {"address": f"10.0.0.{n}"} for n, h in enumerate("abc", 1)}})
    assert deploy.router_links(i) == links


def test_explicit_connect_and_hub() -> None:
    d = inv(hub="robot2")
    d["hosts"]["robot1"]["connect"] = ["broker", "robot2"]
    i = deploy.parse_inventory(d)
    assert deploy.router_links(i) == {"broker": ("robot2",), "robot1": ("broker", "robot2"), "robot2": ()}


def test_acl_by_role() -> None:
    acl = deploy.access_control(deploy.parse_inventory(inv(world="lab")))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    subjects = {s["id"]: s for s in acl["subjects"]}
    policies = {p["id"]: p for p in acl["policies"]}
    assert subjects["routers"] == {"id": "routers", "cert_common_names": ["broker", "robot1", "robot2"]}
    assert subjects["app-m1"] == {"id": "app-m1", "usernames": ["app1"], "cert_common_names": ["app1"]}
    assert rules["app-m1/publish/in"]["key_exprs"] == [
        "uwsimnet/lab/modem/m1/tx", "uwsimnet/lab/pose/*", "uwsimnet/lab/vehicle/*/cmd"]
    assert rules["app-m1/publish/in"]["flows"] == ["ingress"]
    assert rules["app-m1/publish/out"]["messages"] == ["declare_subscriber"]
    # the app's publishers see the broker's wildcard subscribers (issue #18: modem/*/tx, pose/**)
    assert {"uwsimnet/lab/modem/*/tx", "uwsimnet/lab/pose/**"} <= set(rules["app-m1/publish/out"]["key_exprs"])
    assert "uwsimnet/lab/modem/*/info" in rules["app-m1/query/out2"]["key_exprs"]
    assert rules["app-m1/query/out2"]["messages"] == ["declare_queryable"]
    assert rules["driver/token/in"]["key_exprs"] == ["uwsimnet/lab/modem/*/driver/real"]
    assert rules["broker/token/in"]["key_exprs"] == ["uwsimnet/lab/modem/*/driver/sim"]
    assert set(policies["visitor"]["rules"]) == {"visitor/subscribe/in", "visitor/subscribe/out"}
    assert rules["visitor/subscribe/out"]["key_exprs"] == ["uwsimnet/lab/trace/*"]
    # nobody but a driver may declare driver/real, nobody but the broker driver/sim
    for rid, r in rules.items():
        if "liveliness_token" in r["messages"] and r["flows"] == ["ingress"] and rid != "router-all":
            assert rid.startswith(("driver", "broker")), rid
    # every policy names existing rules and subjects
    for p in acl["policies"]:
        assert set(p["rules"]) <= set(rules) and set(p["subjects"]) <= set(subjects)


def test_identities_with_same_rights_share_a_subject() -> None:
    d = inv()
    d["identities"].append({"name": "app2", "role": "app", "host": "robot2", "modems": ["m1"]})
    d["identities"].append({"name": "app3", "role": "app", "host": "robot2"})
    acl = deploy.access_control(deploy.parse_inventory(d))
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert subjects["app-m1"]["usernames"] == ["app1", "app2"]
    assert subjects["app"]["usernames"] == ["app3"]


@pytest.mark.parametrize(("change", "message"), [
    ({"hosts": {}}, "hosts"),
    ({"bogus": 1}, "unknown key"),
    ({"world": "a/b"}, "world"),
    ({"topology": "ring"}, "topology"),
    ({"hub": "nowhere"}, "hub"),
    ({"port": 70000}, "port"),
    ({"identities": [{"name": "x", "role": "admin", "host": "broker"}]}, "role"),
    ({"identities": [{"name": "x", "role": "app", "host": "laptop"}]}, "router"),
    ({"identities": [{"name": "x y", "role": "app", "host": "broker"}]}, "name"),
    ({"identities": [{"name": "broker", "role": "app", "host": "broker"}]}, "already used"),
    ({"identities": [{"name": "x", "role": "visitor", "host": "broker", "modems": ["m"]}]}, "modems"),
    ({"identities": [{"name": "x", "role": "app", "host": "broker", "modems": ["a/b"]}]}, "modem id"),
])
def test_inventory_errors(change: dict[str, Any], message: str) -> None:
    with pytest.raises(deploy.InventoryError, match=message):
        deploy.parse_inventory(inv(**change), "inv.toml")


def test_bad_host_fields() -> None:
    d = inv()
    d["hosts"]["robot1"] = {"address": "10.77.0.2", "connect": ["robot1"]}
    with pytest.raises(deploy.InventoryError, match="not another host"):
        deploy.parse_inventory(d)
    d["hosts"]["robot1"] = {}
    with pytest.raises(deploy.InventoryError, match="address"):
        deploy.parse_inventory(d)


def test_cert_specs() -> None:
    specs = deploy.cert_specs(deploy.parse_inventory(inv()))
    assert specs[0] == "broker=IP:10.77.0.1,IP:127.0.0.1,IP:::1,DNS:localhost"
    assert specs[3:] == ["sim", "app1", "s2c", "guest"]
    d = inv()
    d["hosts"]["broker"]["address"] = "broker.lab"
    assert deploy.cert_specs(deploy.parse_inventory(d))[0].startswith("broker=DNS:broker.lab,")


def test_cli_render_keeps_passwords(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert cli_main(["deploy", "render", str(EXAMPLE), "-o", str(out)]) == 0
    first = (out / "passwords.txt").read_text()
    assert cli_main(["deploy", "render", str(EXAMPLE), "-o", str(out)]) == 0
    assert (out / "passwords.txt").read_text() == first
    assert cli_main(["deploy", "certs", str(EXAMPLE), str(tmp_path / "tls")]) == 0
    assert "make-certs.sh" in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text("hosts = 3\n")
    assert cli_main(["deploy", "render", str(bad), "-o", str(out)]) == 2
    assert "bad.toml" in capsys.readouterr().err


def test_json5_output_is_compact_and_loads() -> None:
    text = deploy.dumps_json5({"a": [1, 2], "b": {"c": "d"}, "e-f": [{"x": 1}], "g": []})
    assert "a: [1, 2]" in text and '"e-f": [\n    { x: 1 },' in text and "g: []" in text
    zenoh = pytest.importorskip("zenoh")
    conf = {"mode": "client", "connect": {"endpoints": ["tcp/127.0.0.1:1"]},
            "scouting": {"multicast": {"enabled": False}}}
    assert json.loads(str(zenoh.Config.from_json5(deploy.dumps_json5(conf))))["connect"]["endpoints"] == \
        ["tcp/127.0.0.1:1"]


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is not installed")
def test_make_certs(tmp_path: Path) -> None:
    script = ROOT / "deploy" / "tls" / "make-certs.sh"
    r = subprocess.run([str(script), str(tmp_path), "r1=IP:10.0.0.1", "alice"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    for f in ("ca.pem", "ca.key", "r1.pem", "r1.key", "alice.pem", "alice.key"):
        assert (tmp_path / f).stat().st_mode & 0o077 == 0, f
    text = subprocess.run(["openssl", "x509", "-in", str(tmp_path / "r1.pem"), "-noout", "-text"],
                          capture_output=True, text=True, check=True).stdout
    assert "CN = r1" in text or "CN=r1" in text
    assert "IP Address:10.0.0.1" in text and "DNS:r1" in text
    assert "TLS Web Server Authentication" in text and "TLS Web Client Authentication" in text
    ok = subprocess.run(["openssl", "verify", "-CAfile", str(tmp_path / "ca.pem"), str(tmp_path / "alice.pem")],
                        capture_output=True, text=True)
    assert ok.returncode == 0
    # a second run keeps the CA and existing certificates
    ca = (tmp_path / "ca.pem").read_bytes()
    r = subprocess.run([str(script), str(tmp_path), "alice", "bob"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "kept" in r.stdout and (tmp_path / "bob.pem").exists()
    assert (tmp_path / "ca.pem").read_bytes() == ca
    bad = subprocess.run([str(script), str(tmp_path), "no/slash"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "bad name" in bad.stderr


def test_every_session_command_uses_the_files_endpoints_and_names_them(tmp_path: Path) -> None:
    """Issue #18: `uwsimnet vehicles/driver/emulate/bridge --zenoh-config FILE` dialled 127.0.0.1:7447
    whatever the file said.  Now each connects to the file's endpoint and, when nothing listens there,
    says so in one line (the endpoint and the file) with exit code 2; so does `gli`."""
    import socket
    import sys

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]                   # closed again: nothing listens there
    conf = tmp_path / "c.json5"
    conf.write_text(f'{{ mode: "client", connect: {{ endpoints: ["tcp/127.0.0.1:{port}"] }} }}\n')
    uw = [sys.executable, "-m", "uwsimnet_zenoh.cli"]
    cmds = [[*uw, "vehicles", "--vehicle", "v=0,0,0", "--world", "w"],
            [*uw, "driver", "serial", "--device", "/dev/null", "--id", "m", "--world", "w"],
            [*uw, "emulate", "serial", "--id", "m", "--world", "w"],
            [*uw, "bridge", "socket", "--id", "m", "--world", "w"]]
    procs = [subprocess.Popen([*c, "--zenoh-config", str(conf)], text=True, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE) for c in cmds]
    procs.append(subprocess.Popen([sys.executable, "-m", "uwsimnet_gli.cli", "--zenoh-config", str(conf), "-w", "w",
                                   "info"], text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE))
    for p in procs:
        out, err = p.communicate(timeout=60)
        lines = err.strip().splitlines()
        assert p.returncode == 2 and len(lines) == 1, (p.args, out, err)
        assert f"cannot connect to tcp/127.0.0.1:{port}" in lines[0], lines[0]
        if "uwsimnet_zenoh.cli" in p.args:
            assert f"(from {conf})" in lines[0], lines[0]


def test_deployment_page_holds_the_generated_roles_table() -> None:
    page = (Path(__file__).resolve().parents[1] / "docs" / "deployment.md").read_text(encoding="utf-8")
    assert deploy.roles_markdown() in page, "regenerate the table of docs/deployment.md: render.roles_markdown()"


def test_client_files_carry_exactly_the_routers_rules_for_them() -> None:
    """metadata.uwsimnet of each client file: what the commands check before declaring anything; the same
    keys as the ingress rules of its group in the routers' access control."""
    i = deploy.parse_inventory(inv(world="lab"))
    app = deploy.client_config(i, "app1", deploy.make_passwords(i))["metadata"]["uwsimnet"]
    assert app["identity"] == "app1" and app["role"] == "app" and app["world"] == "lab"
    rules = {r["id"]: r for r in deploy.access_control(i)["rules"]}
    for cap, keys in app["allow"].items():
        assert [f"uwsimnet/lab/{k}" for k in keys] == rules[f"app-m1/{cap}/in"]["key_exprs"], cap
    assert "modem/m1/tx" in app["allow"]["publish"] and "modem/m2/tx" not in app["allow"]["publish"]


def test_vehicles_restrict_apps_only() -> None:
    d = inv()
    d["identities"][1]["vehicles"] = ["r1"]
    i = deploy.parse_inventory(d)
    acl = {r["id"]: r for r in deploy.access_control(i)["rules"]}
    assert acl["app-m1-v.r1/publish/in"]["key_exprs"] == ["uwsimnet/*/modem/m1/tx", "uwsimnet/*/pose/r1",
                                                          "uwsimnet/*/vehicle/r1/cmd"]
    d["identities"][2]["vehicles"] = ["r1"]
    with pytest.raises(deploy.InventoryError, match="vehicles only restrict apps"):
        deploy.parse_inventory(d)
