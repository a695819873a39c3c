"""The import contracts of docs/architecture.md, read from the source: every import, at the top, inside
functions and under TYPE_CHECKING.  A room imports only rooms below it; siblings never import each other;
nothing below the sans-IO line imports zenoh, rich or matplotlib; the client package never imports the
simulator."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "uwsimnet_zenoh"
GLI = ROOT / "gli_clients" / "python" / "uwsimnet_gli"

# (level, room): a room may import rooms of a lower level only; rooms of one level are siblings.
LAYERS: dict[str, int] = {
    "errors": 0, "_native": 0, "kernel": 1,   # _native: the list of compiled modules and its guard (stdlib only)
    "trace": 2, "mobility": 2, "formats": 2,   # formats: device formats (dccomms framings, EvoLogics AT)
    "phy": 3, "mac": 3,
    "scene": 4,
    "traffic": 5,
    "engine": 6, "analysis": 6, "ros2": 6,   # ros2: rmw_zenoh's wire and the ROS<->sim translation, sans-IO
    # ---- the sans-IO line (uwsimnet_gli.wire sits here, outside this package) ----
    "assembly": 7,                    # a run's outputs (files, never Zenoh): app/ and drivers/ share them
    "bus": 8, "deploy": 8,
    "drivers": 9,
    "bridges": 10,
    "app": 11, "view": 11,            # view: the web page (live Zenoh client + trace replay), beside app
    "experiments": 12,
    "cli": 13,                        # the one command: dispatches to experiments too (DESIGN had them siblings)
}
SANS_IO_LEVEL = 6                     # rooms at or below it are the core
CORE_FORBIDDEN = ("zenoh", "rich", "matplotlib", "uwsimnet_gli")
CORE_EXCEPTIONS = {("analysis", "rich"), ("analysis", "matplotlib")}   # analysis: above the run path
# the package's top-level face may import anything (lazily); it is nobody's dependency inside
FACE = "__init__"


def _type_only_lines(tree: ast.AST) -> set[int]:
    """Lines of imports under `if TYPE_CHECKING:` (annotations only: never run)."""
    lines = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test):
            for b in n.body:
                for m in ast.walk(b):
                    if isinstance(m, ast.Import | ast.ImportFrom):
                        lines.add(m.lineno)
    return lines


def _imports(path: Path, module: str, *, runtime_only: bool = False) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in a file, relative ones resolved (`runtime_only`: without
    the TYPE_CHECKING ones)."""
    tree = ast.parse(path.read_text(), str(path))
    skip = _type_only_lines(tree) if runtime_only else set()
    pkg = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Import | ast.ImportFrom) and n.lineno in skip:
            continue
        if isinstance(n, ast.Import):
            out += [(n.lineno, a.name) for a in n.names]
        elif isinstance(n, ast.ImportFrom):
            if n.level:
                base = pkg[:len(pkg) - (n.level - 1)]
                mod = ".".join(base + ([n.module] if n.module else []))
                if not n.module:                       # from . import a, b: each name is a module
                    out += [(n.lineno, f"{mod}.{a.name}") for a in n.names]
                    continue
            else:
                mod = n.module or ""
            out.append((n.lineno, mod))
    return out


def _files(root: Path, top: str) -> list[tuple[Path, str]]:
    out = []
    for p in sorted(root.rglob("*.py")):
        rel = p.relative_to(root.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out.append((p, ".".join(parts)))
    return out


def _room(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "uwsimnet_zenoh":
        return None
    return parts[1] if len(parts) > 1 else FACE


def _violations(pkg: Path = PKG, gli: Path = GLI) -> list[str]:
    bad = []
    root = pkg.parent
    for path, mod in _files(pkg, "uwsimnet_zenoh"):
        room = _room(mod)
        where = path.relative_to(root)
        if room == FACE:
            continue
        if room not in LAYERS:
            bad.append(f"{where}: room {room!r} is not in the layer map (add it to docs/architecture.md and here)")
            continue
        level = LAYERS[room]
        for line, imp in _imports(path, mod):
            top = imp.split(".")[0]
            target = _room(imp)
            if level <= SANS_IO_LEVEL and top in CORE_FORBIDDEN and (room, top) not in CORE_EXCEPTIONS:
                bad.append(f"{where}:{line}: core room {room} imports {imp}")
            if target is None or target == room:
                continue
            if target == FACE:
                bad.append(f"{where}:{line}: imports the package face ({imp}); import the room instead")
            elif target not in LAYERS:
                bad.append(f"{where}:{line}: imports unknown room {imp}")
            elif LAYERS[target] >= level:
                rel = "sibling" if LAYERS[target] == level else "higher"
                bad.append(f"{where}:{line}: {room} (level {level}) imports {rel} room {target} ({imp})")
    for path, mod in _files(gli, "uwsimnet_gli"):
        for line, imp in _imports(path, mod):
            if imp.split(".")[0] == "uwsimnet_zenoh":
                bad.append(f"{path.relative_to(gli.parent)}:{line}: the client imports the simulator ({imp})")
    wire = gli / "wire.py"
    if wire.is_file():
        for line, imp in _imports(wire, "uwsimnet_gli.wire"):
            if imp.split(".")[0] not in ("__future__", "math", "re", "dataclasses", "typing", "msgpack"):
                bad.append(f"{wire.relative_to(gli.parent)}:{line}: the wire imports {imp} (msgpack and the"
                           " stdlib only)")
    return bad


def _module_cycles(pkg: Path = PKG) -> list[list[str]]:
    """Import cycles between modules.  Lazy imports count (a cycle hidden in a function is still one);
    TYPE_CHECKING imports do not (two classes of one room may name each other in annotations)."""
    mods = dict((m, p) for p, m in _files(pkg, "uwsimnet_zenoh"))
    graph: dict[str, set[str]] = {}
    for m, p in mods.items():
        deps = set()
        for _, imp in _imports(p, m, runtime_only=True):
            while imp and imp not in mods:            # `from pkg.mod import name`: the module is a prefix
                imp = imp.rpartition(".")[0]
            if imp and imp != m and not m.startswith(imp + "."):   # a package's own parents run first anyway
                deps.add(imp)
        graph[m] = deps
    cycles, state = [], {}

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2
    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    return cycles


def test_import_contracts_hold():
    bad = _violations()
    assert not bad, "\n".join(bad)


def test_no_import_cycle_between_modules():
    cycles = _module_cycles()
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)


def test_the_checker_flags_what_it_forbids(tmp_path):
    pkg = tmp_path / "uwsimnet_zenoh"
    for room, body in {"phy": "from ..mac import base\n", "mac": "", "kernel": "import zenoh\n",
                       "engine": "from ..bus import broker\n", "bus": ""}.items():
        (pkg / room).mkdir(parents=True)
        (pkg / room / "__init__.py").write_text(f'"""{room}"""\n')
        (pkg / room / "m.py").write_text(body)
    (pkg / "mac" / "base.py").write_text("")
    gli = tmp_path / "uwsimnet_gli"
    gli.mkdir()
    (gli / "wire.py").write_text("import zenoh\nfrom uwsimnet_zenoh import kernel\n")
    text = "\n".join(_violations(pkg, gli))
    assert "phy (level 3) imports sibling room mac" in text
    assert "core room kernel imports zenoh" in text
    assert "engine (level 6) imports higher room bus" in text
    assert "the client imports the simulator" in text and "the wire imports zenoh" in text
    (pkg / "mac" / "a.py").write_text("from . import b\n")
    (pkg / "mac" / "b.py").write_text("def f():\n    from .a import x\n")
    assert ["uwsimnet_zenoh.mac.a", "uwsimnet_zenoh.mac.b", "uwsimnet_zenoh.mac.a"] in _module_cycles(pkg)


def test_every_room_says_what_it_is():
    missing = [str(p.relative_to(ROOT)) for p in sorted(PKG.glob("*/__init__.py"))
               if not ast.get_docstring(ast.parse(p.read_text()))]
    assert not missing, f"package __init__ without a docstring: {missing}"


def test_the_checker_sees_lazy_and_type_checking_imports(tmp_path):
    src = tmp_path / "uwsimnet_zenoh" / "phy"
    src.mkdir(parents=True)
    f = src / "x.py"
    f.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..mac.base import Mac\n"
                 "def f():\n    from .. import engine\n    import zenoh\n")
    got = [m for _, m in _imports(f, "uwsimnet_zenoh.phy.x")]
    assert {"uwsimnet_zenoh.mac.base", "uwsimnet_zenoh.engine", "zenoh"} <= set(got)


@pytest.mark.parametrize("room", sorted(r for r, lv in LAYERS.items()
                                          if lv <= SANS_IO_LEVEL and r not in ("errors", "_native")))   # modules
def test_core_rooms_exist(room):
    assert (PKG / room / "__init__.py").is_file()


def test_the_public_face():
    import subprocess
    import sys

    code = ("import sys, uwsimnet_zenoh as uw; assert 'uwsimnet_zenoh.engine' not in sys.modules;"
            "s = uw.load_scene_text('<UWSimScene><simulation><duration>1</duration></simulation></UWSimScene>');"
            "n = uw.Network(s); n.run(); assert isinstance(s, uw.Scene) and n.now == 1.0;"
            "from uwsimnet_zenoh.mac import Mac, MacContext, register, resolve;"
            "assert issubclass(uw.SceneError, uw.UwsimnetError) and 'zenoh' not in sys.modules")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_a_file_does_one_job_within_750_lines_and_the_broker_under_500():
    """Issue #35's size rule: no module over 750 lines; the broker, once 766, stays a turn's glue (< 500)."""
    sizes = {p.relative_to(ROOT).as_posix(): len(p.read_text().splitlines())
             for d in (PKG, GLI) for p in d.rglob("*.py")}
    assert {f: n for f, n in sizes.items() if n > 750} == {}
    assert sizes["uwsimnet_zenoh/bus/broker.py"] < 500
