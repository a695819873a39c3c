"""The engine's compiled modules: the ONE list of what `make` compiles with mypyc, and the guard that keeps
a stale build from running.

`make` (build_native.py at the repository's top) compiles `MODULES` into C extensions beside their
sources, one shared library for all of them (`GROUP`), and writes `_native.json`: the SHA-256 of every
source as it was compiled.  If it cannot (no C compiler, no mypyc, a build error) it says so in one line
and the package runs as pure Python, unchanged.

`guard()` runs on the package's first import, before any of these modules is imported.  It imports every
module of the list from its `.py` (Python would otherwise prefer the extension beside it) when:

- a source differs from what was compiled (edited since the build: the extension is stale),
- an extension of the list is missing, or there is no `_native.json`,
- or the environment says `UWSIMNET_PURE=1`.

All or none: the compiled modules call each other's compiled code directly, so one stale module means
none of the build may run.  The compiled and the pure engine give the same trace bytes
(tests/test_native.py).
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import json
import os
import sys
from importlib.machinery import ModuleSpec
from typing import Any

MODULES: tuple[str, ...] = (
    "uwsimnet_zenoh.kernel.scheduler",
    "uwsimnet_zenoh.kernel.frame",
    "uwsimnet_zenoh.trace.tracer",
    "uwsimnet_zenoh.phy.channel",
    "uwsimnet_zenoh.phy.modem",
    "uwsimnet_zenoh.traffic.flow",
    "uwsimnet_zenoh.analysis.fold",
)
"""Compiled with mypyc when `make` can: the leaves of the per-frame path, each called by plain Python above it:
the scheduler's heap, the frame record, the output port and trace encoder (tracer), the air log and geometry
(channel), the metrics' fold, and, because without them the ratio to ns-3 falls below the floor, the modem
and the flows (docs/benchmarks.md, run 20, says what each buys).  Not the pose table: compiled, it bought
nothing on a still scene and cost 8 % on a moving one (its work is numpy's).  The plug-in surface is plain
Python, never listed here: the contracts (kernel.link, Protocols), the MACs and their base classes (mac/),
the channel-model port (phy.models) and the network (tests/test_native.py holds it).  A compiled class is
native (no monkeypatching it) and names no Protocol as a base; the port's `Listener` is subclassed by
Python listeners (`@mypyc_attr(allow_interpreted_subclasses=True)`)."""

GROUP = "uwsimnet_zenoh._engine"
"""The shared library of the compiled modules: uwsimnet_zenoh/_engine__mypyc.<abi>.so."""

PKG_DIR = os.path.dirname(os.path.abspath(__file__))
MANIFEST = os.path.join(PKG_DIR, "_native.json")
PURE_ENV = "UWSIMNET_PURE"

_state: dict[str, Any] = {"pure": None, "why": ""}


def source(module: str) -> str:
    """The .py file of a module of the package."""
    return os.path.join(os.path.dirname(PKG_DIR), *module.split(".")) + ".py"


def extension(module: str) -> str:
    """The extension file this interpreter would import for a module (or the group library)."""
    return os.path.join(os.path.dirname(PKG_DIR), *module.split(".")) + importlib.machinery.EXTENSION_SUFFIXES[0]


def digest(path: str) -> str:
    import hashlib  # only for a source whose size or time changed: a start reads no source otherwise

    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def digests() -> dict[str, str]:
    """The SHA-256 of every source of the list, as it is on disk now."""
    return {m: digest(source(m)) for m in MODULES}


def stats() -> dict[str, list[int]]:
    """(size, mtime in ns) of every source of the list: as for Python's own .pyc, a source whose size and
    time are those of the build is the one compiled, and only a changed one is hashed."""
    out = {}
    for m in MODULES:
        st = os.stat(source(m))
        out[m] = [st.st_size, st.st_mtime_ns]
    return out


def stale_reason() -> str | None:
    """Why the build beside the sources may not run (None: it matches them and may)."""
    try:
        with open(MANIFEST, encoding="utf-8") as f:
            built = json.load(f)
    except (OSError, ValueError):
        return "not compiled"
    if built.get("suffix") != importlib.machinery.EXTENSION_SUFFIXES[0]:
        return "compiled for another interpreter"
    if built.get("stat") != stats() and built.get("modules") != digests():
        return "a source changed since the build (stale)"
    missing = [m for m in (*MODULES, GROUP + "__mypyc") if not os.path.exists(extension(m))]
    if missing:
        return f"extension missing: {missing[0]}"
    return None


class _FromSource:
    """Imports the listed modules from their .py files (ahead of the extension beside them), and any other
    module of the package that has an extension beside its .py (left by a build of an older list, which the
    next build removes).  A meta path finder by its `find_spec` alone: importlib.abc costs 10 ms of imports."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> ModuleSpec | None:
        if name in MODULES:
            return importlib.util.spec_from_file_location(name, source(name))
        if name.startswith("uwsimnet_zenoh.") and os.path.exists(extension(name)) and os.path.exists(source(name)):
            return importlib.util.spec_from_file_location(name, source(name))
        return None


def guard() -> None:
    """Decide once, before any listed module is imported: compiled (a build that matches its sources) or
    every listed module from source."""
    if _state["pure"] is not None:
        return
    why = "UWSIMNET_PURE=1" if os.environ.get(PURE_ENV, "") not in ("", "0") else stale_reason()
    _state["pure"] = why is not None
    _state["why"] = why or ""
    if why is not None and not any(isinstance(f, _FromSource) for f in sys.meta_path):
        sys.meta_path.insert(0, _FromSource())


def loaded() -> list[str]:
    """The listed modules imported so far that run compiled."""
    return [m for m in MODULES if m in sys.modules
            and not (getattr(sys.modules[m], "__file__", "") or "").endswith(".py")]


def status() -> str:
    """One line: compiled, or pure Python and why."""
    guard()
    return "pure Python: " + _state["why"] if _state["pure"] else f"compiled ({len(MODULES)} modules, mypyc)"
