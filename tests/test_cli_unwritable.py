"""An output path that cannot be written is bad input (issue #36): one line naming the path, exit code 2, no
traceback, for every command that writes one.  The path runs through a regular file (NotADirectoryError), which
root cannot write through either."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes" / "examples" / "two-nodes.xml"


def uwsimnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", *args], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)


@pytest.fixture(scope="module")
def trace(tmp_path_factory) -> Path:
    t = tmp_path_factory.mktemp("unwritable") / "t.jsonl"
    assert uwsimnet("run", str(SCENE), "--trace", str(t), "--duration", "5").returncode == 0
    return t


@pytest.mark.parametrize("cmd", ["run", "plot", "sweep", "experiment"])
def test_an_unwritable_output_path_is_one_line_and_exit_2(cmd, trace, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    bad = blocker / "out"
    args = {"run": ["run", str(SCENE), "--trace", str(bad / "t.jsonl"), "--duration", "5"],
            "plot": ["plot", str(trace), "-o", str(bad)],
            "sweep": ["sweep", str(SCENE), "--seeds", "1-2", "--out", str(bad)],
            "experiment": ["experiment", "phy-layer", "--out", str(bad)]}[cmd]
    p = uwsimnet(*args)
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and str(blocker) in lines[0] and "Not a directory" in lines[0], p.stderr
