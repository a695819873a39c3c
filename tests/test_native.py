"""The compiled engine (uwsimnet_zenoh/_native.py, build_native.py): it gives the same trace bytes as the pure
Python one, and a build that no longer matches its sources never runs.

The tests that need a build skip without one (`make` builds it when it can; the pure run is then all there is).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from uwsimnet_zenoh import _native

ROOT = Path(__file__).resolve().parent.parent
BUILT = _native.stale_reason() is None and os.environ.get(_native.PURE_ENV, "") in ("", "0")
needs_build = pytest.mark.skipif(not BUILT, reason=f"no compiled build here ({_native.status()})")

PROBE = """
import json, sys
from uwsimnet_zenoh import _native
import uwsimnet_zenoh.engine.network, uwsimnet_zenoh.mac.nomac, uwsimnet_zenoh.analysis.fold
from uwsimnet_zenoh.kernel import frame
print(json.dumps({"loaded": _native.loaded(), "status": _native.status(), "edited": hasattr(frame, "EDITED"),
                  "frame_file": frame.__file__}))
"""


def probe(env_extra: dict[str, str] | None = None, pythonpath: Path | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != _native.PURE_ENV}
    env.update(env_extra or {})
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True,
                         cwd=pythonpath or ROOT)
    return json.loads(out.stdout)


def test_pure_flag_imports_every_listed_module_from_source():
    got = probe({_native.PURE_ENV: "1"})
    assert got["loaded"] == []
    assert got["frame_file"].endswith(".py")
    assert got["status"] == "pure Python: UWSIMNET_PURE=1"


def test_the_list_names_modules_that_exist():
    for m in _native.MODULES:
        assert Path(_native.source(m)).is_file(), m


PLUGIN_SURFACE = ("uwsimnet_zenoh.kernel.link", "uwsimnet_zenoh.mac.base", "uwsimnet_zenoh.mac.nomac",
                  "uwsimnet_zenoh.mac.testing", "uwsimnet_zenoh.phy.models", "uwsimnet_zenoh.engine.network")


def test_what_a_plugin_author_subclasses_or_implements_is_never_compiled():
    """Issue #35 item 5: only leaves are compiled; the MAC contract, the MAC base classes, the channel-model
    base and the network stay plain Python (no compiler rule in docs/mac.md), compiled build or not."""
    import importlib

    assert not set(PLUGIN_SURFACE) & set(_native.MODULES)
    for m in PLUGIN_SURFACE:
        assert importlib.import_module(m).__file__.endswith(".py"), m
    text = (ROOT / "docs" / "mac.md").read_text()
    assert "mypyc" not in text and "compiled" not in text


@needs_build
def test_this_process_runs_the_compiled_engine():
    import uwsimnet_zenoh.analysis.fold  # noqa: F401
    import uwsimnet_zenoh.engine.network  # noqa: F401
    import uwsimnet_zenoh.mac.nomac  # noqa: F401

    assert _native.loaded() == list(_native.MODULES)



@needs_build
def test_the_metrics_state_is_not_tracked_by_the_cyclic_gc():
    """The fold keeps one FrameState per frame to the end of a run: compiled as acyclic classes, the cyclic
    GC never walks them (it did, ~1 us a frame, in collections during and after the run); a run still
    leaves its metrics intact."""
    import gc

    from uwsimnet_zenoh.analysis import fold
    from uwsimnet_zenoh.analysis.metrics import Accumulator

    states = [fold.FrameState("s0", 1, 0, 0, 0), fold.FlowState("f", "s0", 0, 37), fold.ChannelState(),
              fold.Receiver("sink", 1, 0, None, 1)]
    assert [gc.is_tracked(s) for s in states] == [False] * 4
    acc = Accumulator({})
    acc.event(0.5, "enq", 0, "s0", 1, 0, 7, 40, "f", "data", None, False)
    acc.event(0.75, "tx", 0, "s0", 1, 0, 7, 40, "f", "data", None, False)
    acc.event(1.25, "rx", 0, "sink", 1, 0, 7, 40, "f", "data", None, True)
    gc.collect()
    m = acc.result().flows["f"]
    assert (m.enqueued, m.sent, m.delivered) == (1, 1, 1)

def _copy_package(tmp_path: Path) -> Path:
    dst = tmp_path / "uwsimnet_zenoh"
    shutil.copytree(ROOT / "uwsimnet_zenoh", dst, ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


@needs_build
def test_a_copy_of_the_build_runs_compiled(tmp_path):
    """The control for the next test: the copied tree, untouched, loads its extensions."""
    got = probe(pythonpath=_copy_package(tmp_path))
    assert got["loaded"] == list(_native.MODULES)
    assert got["frame_file"].startswith(str(tmp_path))


@needs_build
@pytest.mark.parametrize("module", ["uwsimnet_zenoh.kernel.frame", "uwsimnet_zenoh.phy.modem"])
def test_an_edited_source_makes_the_whole_build_stale(tmp_path, module):
    """A source edited after the build: every listed module is imported from its .py (the edit runs), none
    of the extensions; not only the edited one, since the compiled modules call each other directly."""
    root = _copy_package(tmp_path)
    src = root / Path(*module.split(".")).with_suffix(".py")
    text = src.read_text()
    src.write_text(text + ("\nEDITED = True\n" if module.endswith("frame") else "\n# a comment only\n"))
    got = probe(pythonpath=root)
    assert got["loaded"] == []
    assert got["status"] == "pure Python: a source changed since the build (stale)"
    assert got["edited"] == module.endswith("frame")
    assert got["frame_file"] == str(root / "uwsimnet_zenoh" / "kernel" / "frame.py")


@needs_build
def test_a_missing_extension_or_manifest_means_pure(tmp_path):
    root = _copy_package(tmp_path)
    ext = Path(_native.extension("uwsimnet_zenoh.phy.channel"))
    (root / ext.relative_to(ROOT)).unlink()
    got = probe(pythonpath=root)
    assert got["loaded"] == [] and got["status"].startswith("pure Python: extension missing")
    (root / "uwsimnet_zenoh" / "_native.json").unlink()
    assert probe(pythonpath=root)["status"] == "pure Python: not compiled"


@needs_build
def test_an_extension_left_by_an_older_list_is_not_imported_when_pure(tmp_path):
    """A module compiled by an older list (mac.base was, before issue #35 item 5) whose extension is still
    beside its source: the pure engine imports its .py (the next build removes the file)."""
    root = _copy_package(tmp_path)
    def inside(module: str) -> Path:
        return root / Path(_native.extension(module)).relative_to(ROOT)

    shutil.copy(inside("uwsimnet_zenoh.kernel.frame"), inside("uwsimnet_zenoh.mac.base"))
    (root / "uwsimnet_zenoh" / "_native.json").unlink()
    env = {k: v for k, v in os.environ.items() if k != _native.PURE_ENV}
    out = subprocess.run([sys.executable, "-c", "import uwsimnet_zenoh.mac.base as b; print(b.__file__)"],
                         env={**env, "PYTHONPATH": str(root)}, capture_output=True, text=True, check=True, cwd=root)
    assert out.stdout.strip() == str(root / "uwsimnet_zenoh" / "mac" / "base.py")


RUN = """
import json, sys
from pathlib import Path
from uwsimnet_zenoh import _native
from uwsimnet_zenoh.analysis import report_json
from uwsimnet_zenoh.app.virtual import load_scene_file, simulate
sc = load_scene_file(sys.argv[1])
a = simulate(sc, seed=int(sys.argv[2]), duration=float(sys.argv[3]), trace_path=Path(sys.argv[4]),
             progress=False).analysis
print(json.dumps([report_json(a.flows), {str(k): c.to_dict() for k, c in a.channels.items()}, list(a.conservation),
                  [list(x.__dict__.values()) for x in a.conservation.in_flight]], sort_keys=True))
print(len(_native.loaded()))
"""

SCENES = [("scenes/paper/phy-layer-rf.xml", "3", "60"), ("scenes/paper/twinbot-sfama.xml", "1", "60"),
          ("scenes/examples/acoustic-capture.xml", "1", "60")]


@needs_build
@pytest.mark.parametrize("scene, seed, duration", SCENES)
def test_compiled_and_pure_give_the_same_trace_bytes(tmp_path, scene, seed, duration):
    """... and the same online summary (the metrics' fold is compiled too)."""
    outs, summaries = [], []
    for pure in ("1", "0"):
        out = tmp_path / f"pure{pure}.jsonl"
        env = {**os.environ, _native.PURE_ENV: pure}
        r = subprocess.run([sys.executable, "-c", RUN, str(ROOT / scene), seed, duration, str(out)], env=env,
                           capture_output=True, text=True, check=True, cwd=ROOT)
        assert int(r.stdout.split()[-1]) == (0 if pure == "1" else len(_native.MODULES))
        outs.append(out.read_bytes())
        summaries.append(r.stdout.splitlines()[-2])
    assert outs[0].count(b"\n") > 100
    assert outs[0] == outs[1]
    assert '"delivered"' in summaries[0] and summaries[0] == summaries[1]
