"""Per-machine Zenoh configurations from a small inventory: routers, clients, TLS, passwords, access control.

The topology of DESIGN.md: one router per machine (`uwsimnet router --config <host>/router.json5`),
everything on a machine a client of its router, routers connected to each other over mutual TLS.
Every identity (a router, the broker, a driver, an app, a visitor) authenticates twice: a certificate
whose CN is its name (mutual TLS) and a user/password (`transport/auth/usrpwd`).  Every router carries the
same access-control list: what each role may put, subscribe, query, serve and declare on which keys of
the key space, built from what the role's programs declare (`uwsimnet_gli.wire.USES`, `ROLES`; the
table is in docs/deployment.md).  Anything not allowed is denied.  Each client file also carries its
identity's rights (`metadata.uwsimnet`), which the commands check before declaring anything.

    uwsimnet deploy render INVENTORY.toml -o OUTDIR   # OUTDIR/<host>/... per machine
    uwsimnet deploy certs INVENTORY.toml TLSDIR       # the make-certs.sh command
    uwsimnet deploy check OUTDIR                      # every generated file loads in zenoh

Inventory (TOML, see deploy/inventory.example.toml):

    world = "*"                  # world name the ACL covers, "*" = every world
    port = 7447                  # routers' TLS port (a host may override)
    topology = "star"            # star (around `hub`) | chain (in order) | mesh
    hub = "broker"               # the star's centre (default: the first host)
    tls_dir = "/etc/uwsimnet/tls"   # on every machine: ca.pem + that machine's NAME.pem/NAME.key
    etc_dir = "/etc/uwsimnet/{host}"  # on every machine: the files of OUTDIR/<host>/ ("{host}" is replaced)

    [hosts.broker]               # one router per host, named after the host
    address = "10.77.0.1"        # where the other machines reach it
    # port, listen = [...], connect = ["other-host", ...]  (overrides the topology)

    [[identities]]
    name = "sim"                 # certificate CN and user name (unique among hosts and identities)
    role = "broker"              # broker | driver | app | operator | visitor
    host = "broker"              # the machine it runs on (its config lands in OUTDIR/<host>/clients/)
    # router = "broker"          # the host whose router it connects to (default: host, over loopback)
    # modems = ["m1"]            # driver/app: only these modem ids (default: all)
    # vehicles = ["v1"]          # app: only these vehicles (default: all)

`render()` does no I/O: it returns {relative path: text}; passwords not given are generated (keep the
`passwords.txt` it returns: `render` reuses it so that re-rendering does not lock existing clients out).
"""

from __future__ import annotations

import json
import re
import secrets
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwsimnet_gli import wire

from ..errors import UwsimnetError

PREFIX = wire.PREFIX
ROLE_NAMES = ("broker", "driver", "app", "operator", "visitor")
ROUTER_ROLE = "router"
TOPOLOGIES = ("star", "chain", "mesh")
DEFAULT_PORT = 7447

ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")


@dataclass(frozen=True)
class Role:
    """What an identity may do: the programs of `uwsimnet_gli.wire.USES` it runs (their declarations,
    with `{m}` = the identity's modems and `{v}` its vehicles), and the commands that run them."""

    programs: tuple[str, ...]
    commands: tuple[str, ...]
    doc: str = ""

    def uses(self, cap: str) -> tuple[str, ...]:
        """The relative key templates of capability `cap` (publish, subscribe, ...) over its programs."""
        return tuple(dict.fromkeys(k for p in self.programs for k in wire.USES[p].keys(cap)))


ROLES: dict[str, Role] = {
    "broker": Role(("broker",), ("uwsimnet run SCENE --clock realtime",),
                   "the simulator: serves the scene's modems, publishes rx/status/trace/clock and scene poses"),
    "driver": Role(("driver", "backend"),
                   ("uwsimnet driver evologics/serial --id M", "uwsimnet emulate evologics/serial --id M",
                    "uwsimnet bridge socket/mq --id M"),
                   "a real modem (HIL) that takes its modems over, or an emulator/bridge on the modem's host"),
    "app": Role(("modem", "listen", "info", "pose", "poses", "command", "clock", "trace",
                 "vehicles", "backend"),
                ("gli send/flow M", "gli listen M", "gli info M", "gli pose V", "gli vehicle V",
                 "gli trace", "uwsimnet vehicles --vehicle V=X,Y,Z", "uwsimnet emulate ... --id M",
                 "uwsimnet bridge ... --id M"),
                "an application or robot: sends and receives on its modems, moves its vehicles"),
    "operator": Role(("control", "trace", "info", "poses", "clock"),
                     ("gli control OP", "uwsimnet view --world W", "gli trace", "gli info"),
                     "runs the run: pause/resume, move any vehicle, add/remove modems (#41: never an app's right)"),
    "visitor": Role(("trace",), ("gli trace",), "read-only: trace events, nothing else"),
}
"""The access of every role.  Routers may do everything."""


CAPABILITIES: dict[str, tuple[tuple[str, tuple[str, ...], str], ...]] = {
    # capability: (flow, messages, on which keys) - "own": the role's keys; "seen": its keys plus every
    # declaration of the other side (any program's) that intersects them.  Measured on eclipse-zenoh 1.10
    # (tests/test_security.py, tests/test_deploy_matrix.py).
    "publish": (("ingress", ("put", "delete"), "own"),
                ("egress", ("declare_subscriber",), "seen")),  # a Publisher only sends where it sees subscribers
    "subscribe": (("ingress", ("declare_subscriber",), "own"),
                  ("egress", ("put", "delete"), "own")),
    "query": (("ingress", ("query",), "own"),
              ("egress", ("reply",), "own"),
              ("egress", ("declare_queryable",), "seen")),   # a Querier needs to see the queryables
    "serve": (("ingress", ("declare_queryable", "reply"), "own"),
              ("egress", ("query",), "seen")),               # `gli info` asks modem/*/info
    "token": (("ingress", ("liveliness_token",), "own"),),
    "watch": (("ingress", ("declare_liveliness_subscriber", "liveliness_query"), "own"),
              ("egress", ("liveliness_token",), "own")),
}
"""What each capability allows on the router, in which direction (ingress: from the client to its router;
egress: from the router to the client), on which keys."""

COUNTERPART = {"publish": "subscribe", "query": "serve", "serve": "query"}
"""Whose declarations a capability must see: a publisher the subscribers, a querier the queryables, ..."""


def role_keys(role: Role, cap: str, modems: Sequence[str] = (), vehicles: Sequence[str] = ()) -> list[str]:
    """Relative key expressions of `cap` for an identity with these modems and vehicles (none: all)."""
    return list(dict.fromkeys(k for t in role.uses(cap) for k in wire.expand(t, modems, vehicles)))


def seen_keys(cap: str, own: Sequence[str]) -> list[str]:
    """`own` plus every declaration of the counterpart capability, by any program, that intersects them
    (the broker's `modem/*/tx` subscriber for an app publishing on `modem/a/tx`)."""
    other = [k for u in wire.USES.values() for t in u.keys(COUNTERPART[cap]) for k in wire.expand(t)]
    return list(dict.fromkeys([*own, *(o for o in other if any(wire.intersects(o, k) for k in own))]))


def role_rules(role: Role, modems: Sequence[str] = (), vehicles: Sequence[str] = ()
               ) -> list[tuple[str, str, tuple[str, ...], list[str]]]:
    """(capability, flow, messages, relative keys) for every capability the role uses."""
    out = []
    for cap, triples in CAPABILITIES.items():
        own = role_keys(role, cap, modems, vehicles)
        if own:
            out.extend((cap, flow, msgs, own if which == "own" else seen_keys(cap, own))
                       for flow, msgs, which in triples)
    return out


def roles_markdown() -> str:
    """The roles table of docs/deployment.md (tests/test_deploy.py checks the page holds this text)."""
    caps = wire.CAPABILITIES
    head = "| role | runs | " + " | ".join(caps) + " |\n|" + "---|" * (len(caps) + 2) + "\n"
    rows = []
    for name, role in ROLES.items():
        cells = [", ".join(f"`{k}`" for k in role.uses(c)) or "-" for c in caps]
        rows.append(f"| **{name}** | " + "<br>".join(f"`{c}`" for c in role.commands) + " | " + " | ".join(cells)
                    + " |")
    return head + "\n".join(rows) + "\n"


class InventoryError(UwsimnetError, ValueError):
    """The inventory is not usable; the message says where and why."""


_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_CHUNK = re.compile(r"^[^/*$?#\s]+$")


@dataclass(frozen=True)
class Host:
    name: str
    address: str
    port: int
    listen: tuple[str, ...]
    connect: tuple[str, ...] | None = None  # host names; None = from the topology


@dataclass(frozen=True)
class Identity:
    name: str
    role: str
    host: str
    router: str
    modems: tuple[str, ...] = ()
    vehicles: tuple[str, ...] = ()


@dataclass(frozen=True)
class Inventory:
    hosts: dict[str, Host]
    identities: dict[str, Identity]
    world: str = "*"
    topology: str = "star"
    hub: str = ""
    tls_dir: str = "/etc/uwsimnet/tls"
    etc_dir: str = "/etc/uwsimnet/{host}"
    source: str = "<inventory>"

    def etc(self, host: str) -> str:
        return self.etc_dir.replace("{host}", host)

    def tls(self, name: str, host: str) -> dict[str, str]:
        d = self.tls_dir.replace("{host}", host)
        return {"ca": f"{d}/ca.pem", "cert": f"{d}/{name}.pem", "key": f"{d}/{name}.key"}

    def endpoint(self, host: str, *, local: bool) -> str:
        h = self.hosts[host]
        addr = "127.0.0.1" if local else h.address
        return f"tls/{_bracket(addr)}:{h.port}"


def _bracket(addr: str) -> str:
    return f"[{addr}]" if ":" in addr and not addr.startswith("[") else addr


def _name(v: Any, where: str) -> str:
    if not isinstance(v, str) or not _NAME.match(v):
        raise InventoryError(f"{where}: name {v!r} must be letters, digits, '.', '_' or '-' (it is a CN and a user)")
    return v


def _strs(v: Any, where: str) -> tuple[str, ...]:
    if not isinstance(v, list) or not all(isinstance(x, str) and x for x in v):
        raise InventoryError(f"{where}: expected a list of strings")
    return tuple(v)


def _keys(d: Mapping[str, Any], allowed: set[str], where: str) -> None:
    bad = sorted(set(d) - allowed)
    if bad:
        raise InventoryError(f"{where}: unknown key(s) {', '.join(bad)} (allowed: {', '.join(sorted(allowed))})")


def parse_inventory(data: Mapping[str, Any], source: str = "<inventory>") -> Inventory:
    """Check an inventory (the TOML document as a dict) and fill in its defaults."""
    top = {"world", "port", "topology", "hub", "tls_dir", "etc_dir", "hosts", "identities"}
    _keys(data, top, source)
    world = data.get("world", "*")
    if not isinstance(world, str) or not _CHUNK.match(world.replace("*", "x")) or (
            "*" in world and world != "*"):
        raise InventoryError(f"{source}: world {world!r} must be one key chunk, or '*' for every world")
    port = data.get("port", DEFAULT_PORT)
    if not isinstance(port, int) or not 0 < port < 65536:
        raise InventoryError(f"{source}: port {port!r} must be a TCP port number")
    raw_hosts = data.get("hosts")
    if not isinstance(raw_hosts, dict) or not raw_hosts:
        raise InventoryError(f"{source}: [hosts.<name>] tables are required (one router per machine)")
    hosts: dict[str, Host] = {}
    for name, h in raw_hosts.items():
        where = f"{source}: hosts.{name}"
        _name(name, where)
        if not isinstance(h, dict):
            raise InventoryError(f"{where}: expected a table")
        _keys(h, {"address", "port", "listen", "connect"}, where)
        addr = h.get("address")
        if not isinstance(addr, str) or not addr:
            raise InventoryError(f"{where}: address (IP or DNS name other machines reach it at) is required")
        hport = h.get("port", port)
        if not isinstance(hport, int) or not 0 < hport < 65536:
            raise InventoryError(f"{where}: port {hport!r} must be a TCP port number")
        listen = _strs(h["listen"], f"{where}.listen") if "listen" in h else (f"tls/[::]:{hport}",)
        connect = _strs(h["connect"], f"{where}.connect") if "connect" in h else None
        hosts[name] = Host(name, addr, hport, listen, connect)
    for h in hosts.values():
        for c in h.connect or ():
            if c not in hosts or c == h.name:
                raise InventoryError(f"{source}: hosts.{h.name}.connect: {c!r} is not another host")
    topology = data.get("topology", "star")
    if topology not in TOPOLOGIES:
        raise InventoryError(f"{source}: topology {topology!r} must be one of {', '.join(TOPOLOGIES)}")
    hub = data.get("hub", next(iter(hosts)))
    if hub not in hosts:
        raise InventoryError(f"{source}: hub {hub!r} is not a host")
    idents: dict[str, Identity] = {}
    raw_ids = data.get("identities", [])
    if not isinstance(raw_ids, list):
        raise InventoryError(f"{source}: identities must be [[identities]] tables")
    for i, d in enumerate(raw_ids):
        where = f"{source}: identities[{i}]"
        if not isinstance(d, dict):
            raise InventoryError(f"{where}: expected a table")
        _keys(d, {"name", "role", "host", "router", "modems", "vehicles"}, where)
        name = _name(d.get("name"), where)
        where = f"{source}: identity {name}"
        if name in idents or name in hosts:
            raise InventoryError(f"{where}: the name is already used (names of hosts and identities are unique)")
        role = d.get("role")
        if role not in ROLE_NAMES:
            raise InventoryError(f"{where}: role {role!r} must be one of {', '.join(ROLE_NAMES)}")
        host = d.get("host")
        router = d.get("router", host)
        if router not in hosts:
            raise InventoryError(f"{where}: router {router!r} is not a host (set host, or router)")
        if not isinstance(host, str) or not _NAME.match(host):
            raise InventoryError(f"{where}: host (the machine it runs on) is required")
        modems = _strs(d["modems"], f"{where}.modems") if "modems" in d else ()
        for m in modems:
            if not _CHUNK.match(m):
                raise InventoryError(f"{where}: modem id {m!r} must be one key chunk")
        if modems and role not in ("driver", "app"):
            raise InventoryError(f"{where}: modems only restrict drivers and apps")
        vehicles = _strs(d["vehicles"], f"{where}.vehicles") if "vehicles" in d else ()
        for v in vehicles:
            if not _CHUNK.match(v):
                raise InventoryError(f"{where}: vehicle name {v!r} must be one key chunk")
        if vehicles and role != "app":
            raise InventoryError(f"{where}: vehicles only restrict apps")
        idents[name] = Identity(name, role, host, router, modems, vehicles)
    tls_dir = data.get("tls_dir", "/etc/uwsimnet/tls")
    etc_dir = data.get("etc_dir", "/etc/uwsimnet/{host}")
    if not isinstance(tls_dir, str) or not isinstance(etc_dir, str):
        raise InventoryError(f"{source}: tls_dir and etc_dir must be paths")
    return Inventory(hosts=hosts, identities=idents, world=world, topology=topology, hub=hub,
                     tls_dir=tls_dir.rstrip("/") or "/", etc_dir=etc_dir.rstrip("/") or "/", source=source)


def load_inventory(path: str | Path) -> Inventory:
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise InventoryError(f"{path}: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise InventoryError(f"{path}: {e}") from None
    return parse_inventory(data, str(path))


# -- topology -------------------------------------------------------------------------------------

def router_links(inv: Inventory) -> dict[str, tuple[str, ...]]:
    """For every host, the hosts its router connects to (each pair is connected from one side only)."""
    names = list(inv.hosts)
    out: dict[str, tuple[str, ...]] = {}
    for i, n in enumerate(names):
        h = inv.hosts[n]
        if h.connect is not None:
            out[n] = h.connect
        elif inv.topology == "star":
            out[n] = () if n == inv.hub else (inv.hub,)
        elif inv.topology == "chain":
            out[n] = (names[i - 1],) if i else ()
        else:  # mesh
            out[n] = tuple(names[:i])
    return out


# -- access control -------------------------------------------------------------------------------

def _world_keys(inv: Inventory, rel: Sequence[str]) -> list[str]:
    return [f"{PREFIX}/{inv.world}/{k}" for k in rel]


def access_control(inv: Inventory) -> dict[str, Any]:
    """The `access_control` section every router carries: default deny, one policy per group of identities
    that have the same rights (a role, or a role restricted to given modems/vehicles), one for the routers."""
    rules: list[dict[str, Any]] = [{
        "id": "router-all", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"],
        "permission": "allow", "key_exprs": ["**"]}]
    # a router is known by its certificate only: on the side that opened a link there is no user name
    # (usrpwd authenticates the connecting side to the accepting side only), but both sides see the CN
    subjects: list[dict[str, Any]] = [{"id": "routers", "cert_common_names": sorted(inv.hosts)}]
    policies: list[dict[str, Any]] = [{"id": "routers", "rules": ["router-all"], "subjects": ["routers"]}]
    groups: dict[tuple[str, tuple[str, ...], tuple[str, ...]], list[str]] = {}
    for ident in inv.identities.values():
        groups.setdefault((ident.role, ident.modems, ident.vehicles), []).append(ident.name)
    for (role_name, modems, vehicles), names in groups.items():
        gid = role_name + "".join("-" + x for x in (*modems, *(f"v.{v}" for v in vehicles)))
        rule_ids = []
        seen: dict[str, int] = {}
        for cap, flow, msgs, rel in role_rules(ROLES[role_name], modems, vehicles):
            base = f"{gid}/{cap}/{'in' if flow == 'ingress' else 'out'}"
            seen[base] = seen.get(base, 0) + 1
            rid = base if seen[base] == 1 else f"{base}{seen[base]}"
            rules.append({"id": rid, "messages": list(msgs), "flows": [flow], "permission": "allow",
                          "key_exprs": _world_keys(inv, rel)})
            rule_ids.append(rid)
        # user name AND certificate CN must both be of the group (the fields of one subject are ANDed)
        subjects.append({"id": gid, "usernames": sorted(names), "cert_common_names": sorted(names)})
        policies.append({"id": gid, "rules": rule_ids, "subjects": [gid]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


# -- configurations -------------------------------------------------------------------------------

def _tls_section(inv: Inventory, name: str, host: str, *, listen: bool) -> dict[str, Any]:
    """Mutual TLS: every node presents its certificate (a client only uses its own when enable_mtls is
    set on its side too) and checks the other's against the CA and, when connecting, the address."""
    paths = inv.tls(name, host)
    t: dict[str, Any] = {"root_ca_certificate": paths["ca"]}
    if listen:
        t.update(listen_certificate=paths["cert"], listen_private_key=paths["key"])
    t.update(connect_certificate=paths["cert"], connect_private_key=paths["key"], enable_mtls=True,
             verify_name_on_connect=True)
    return t


def router_config(inv: Inventory, host: str, passwords: Mapping[str, str]) -> dict[str, Any]:
    """The configuration of `host`'s router (a dict; `render` writes it as JSON5)."""
    h = inv.hosts[host]
    links = router_links(inv)[host]
    tls = _tls_section(inv, host, host, listen=True)
    return {
        "mode": "router",
        "listen": {"endpoints": list(h.listen)},
        "connect": {"endpoints": [inv.endpoint(o, local=False) for o in links]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "link": {"protocols": ["tls"], "tls": tls},
            "auth": {"usrpwd": {"user": host, "password": passwords[host],
                                "dictionary_file": f"{inv.etc(host)}/users.txt"}},
        },
        "access_control": access_control(inv),
    }


def client_config(inv: Inventory, name: str, passwords: Mapping[str, str]) -> dict[str, Any]:
    """The configuration of identity `name` (a client of its router)."""
    ident = inv.identities[name]
    local = ident.router == ident.host
    role = ROLES[ident.role]
    allow = {cap: keys for cap in wire.CAPABILITIES
             if (keys := role_keys(role, cap, ident.modems, ident.vehicles))}
    return {
        "mode": "client",
        # what the routers allow it (wire.ACCESS_KEY): commands refuse at once what would be dropped
        "metadata": {wire.ACCESS_KEY: {"identity": name, "role": ident.role, "world": inv.world, "allow": allow}},
        "connect": {"endpoints": [inv.endpoint(ident.router, local=local)]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "link": {"protocols": ["tls"], "tls": _tls_section(inv, name, ident.host, listen=False)},
            "auth": {"usrpwd": {"user": name, "password": passwords[name]}},
        },
    }


def all_names(inv: Inventory) -> list[str]:
    """Every user: the routers (named after their hosts) and the identities."""
    return [*inv.hosts, *inv.identities]


def make_passwords(inv: Inventory, known: Mapping[str, str] | None = None) -> dict[str, str]:
    """The known passwords, plus a fresh random one for every name that has none."""
    out = {}
    for n in all_names(inv):
        pw = (known or {}).get(n) or secrets.token_urlsafe(18)
        if ":" in pw or "\n" in pw:
            raise InventoryError(f"password of {n}: ':' and newlines cannot be in a usrpwd dictionary")
        out[n] = pw
    return out


def parse_passwords(text: str) -> dict[str, str]:
    """`name:password` lines (the usrpwd dictionary format)."""
    out = {}
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#") and ":" in line:
            n, pw = line.split(":", 1)
            out[n] = pw
    return out


_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def dumps_json5(v: Any, indent: int = 0, width: int = 116) -> str:
    """JSON5 text: unquoted identifier keys, short objects and lists on one line (JSON strings otherwise)."""
    flat = _flat(v)
    if flat is not None and indent + len(flat) <= width:
        return flat
    pad, inner = "  " * indent, "  " * (indent + 1)
    if isinstance(v, dict):
        items = [f"{inner}{_key(k)}: {dumps_json5(x, indent + 1, width)}," for k, x in v.items()]
        return "{\n" + "\n".join(items) + f"\n{pad}}}"
    items = [f"{inner}{dumps_json5(x, indent + 1, width)}," for x in v]
    return "[\n" + "\n".join(items) + f"\n{pad}]"


def _key(k: str) -> str:
    return k if _IDENT.match(k) else json.dumps(k)


def _flat(v: Any) -> str | None:
    """One-line JSON5 of v, or None if it holds a list of objects (those get a line each)."""
    if isinstance(v, dict):
        parts = []
        for k, x in v.items():
            fx = _flat(x)
            if fx is None:
                return None
            parts.append(f"{_key(k)}: {fx}")
        return "{ " + ", ".join(parts) + " }" if parts else "{}"
    if isinstance(v, list):
        if any(isinstance(x, dict | list) for x in v):
            return None
        return "[" + ", ".join(json.dumps(x) for x in v) + "]"
    return json.dumps(v)


def _json5(conf: dict[str, Any], what: str, inv: Inventory) -> str:
    head = (f"// {what}\n// generated by `uwsimnet deploy render {inv.source}`:"
            " edit the inventory, not this file\n")
    return head + dumps_json5(conf) + "\n"


def render(inv: Inventory | Mapping[str, Any], passwords: Mapping[str, str] | None = None) -> dict[str, str]:
    """Every file of a deployment, as {path relative to the output directory: text}:

        passwords.txt                    all users and passwords (keep it private; reused on re-rendering)
        <host>/router.json5              that machine's router (`uwsimnet router --config`)
        <host>/router.env                EnvironmentFile of uwsimnet-router@<host>.service
        <host>/users.txt                 the router's usrpwd dictionary
        <host>/clients/<name>.json5      each identity that runs on that machine
        <host>/broker-<name>.env         EnvironmentFile of uwsimnet-broker@<name>.service, per broker

    On each machine, <host>/ goes to etc_dir (default /etc/uwsimnet/<host>).
    """
    if not isinstance(inv, Inventory):
        inv = parse_inventory(inv)
    pw = make_passwords(inv, passwords)
    users = "".join(f"{n}:{pw[n]}\n" for n in all_names(inv))
    out = {"passwords.txt": users}
    for host, h in inv.hosts.items():
        links = ", ".join(router_links(inv)[host]) or "none"
        out[f"{host}/router.json5"] = _json5(router_config(inv, host, pw),
                                             f"router of {host} (connects to: {links})", inv)
        out[f"{host}/users.txt"] = users
        # `uwsimnet router --config` listens on the file's endpoints; repeating them here is harmless
        listen = " ".join(f"--listen={e}" for e in h.listen)
        out[f"{host}/router.env"] = (f"# EnvironmentFile of uwsimnet-router@{host}.service (generated)\n"
                                     f"ROUTER_ARGS={listen}\n")
    for name, ident in inv.identities.items():
        out[f"{ident.host}/clients/{name}.json5"] = _json5(
            client_config(inv, name, pw), f"{name}: {ident.role}, client of the router of {ident.router}", inv)
        if ident.role == "broker":
            etc = inv.etc(ident.host)
            out[f"{ident.host}/broker-{name}.env"] = (
                f"# EnvironmentFile of uwsimnet-broker@{name}.service (generated; set SCENE and BROKER_ARGS)\n"
                f"SCENE={etc}/scenes/{name}.xml\n"
                f"ZENOH_CONFIG={etc}/clients/{name}.json5\n"
                f"CONNECT={inv.endpoint(ident.router, local=ident.router == ident.host)}\n"
                "BROKER_ARGS=\n")
    return out


def write(files: Mapping[str, str], outdir: str | Path) -> list[Path]:
    """Write rendered files (mode 0600: they hold passwords); returns the paths."""
    out = Path(outdir)
    written = []
    for rel, text in files.items():
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        p.touch(mode=0o600, exist_ok=True)
        p.chmod(0o600)
        p.write_text(text, encoding="utf-8")
        written.append(p)
    return written


def cert_specs(inv: Inventory) -> list[str]:
    """The `NAME[=SAN,...]` arguments of deploy/tls/make-certs.sh for an inventory."""
    specs = []
    for h in inv.hosts.values():
        kind = "IP" if re.match(r"^[0-9.]+$|:", h.address) else "DNS"
        sans = [f"{kind}:{h.address.strip('[]')}", "IP:127.0.0.1", "IP:::1", "DNS:localhost"]
        specs.append(f"{h.name}={','.join(dict.fromkeys(sans))}")
    specs.extend(inv.identities)
    return specs


def make_certs_script() -> str:
    """deploy/tls/make-certs.sh of a source checkout (or of /opt/uwsimnet in the container)."""
    for base in (Path(__file__).resolve().parents[2], Path.cwd(), Path("/opt/uwsimnet")):
        p = base / "deploy" / "tls" / "make-certs.sh"
        if p.is_file():
            return str(p)
    return "deploy/tls/make-certs.sh"


def check(outdir: str | Path) -> list[str]:
    """Load every generated .json5 under outdir in zenoh (unknown keys raise); returns the problems."""
    import zenoh  # noqa: PLC0415 - only this command needs it

    problems = []
    for p in sorted(Path(outdir).rglob("*.json5")):
        try:
            zenoh.Config.from_file(str(p))
        except zenoh.ZError as e:
            problems.append(f"{p}: {' '.join(str(e).split())}")
    return problems
