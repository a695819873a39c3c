"""How a Bellhop run that goes wrong reaches the user: `uwsimnet validate` on a scene whose grid is not cached
exits 2 with one `file:line:` line (no traceback) when the program runs over the model's <timeout> or
fails without writing its output; the grid is not cached then.  The programs are real executables (a shell
script that sleeps, /bin/false), named in the scene's <program>, as a user would name their Bellhop."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from uwsimnet_zenoh.phy import bellhop

DATA = Path(__file__).resolve().parent / "data"
SCENE = DATA / "ocean-shadow.xml"


def _validate(tmp_path: Path, extra: str) -> tuple[subprocess.CompletedProcess, Path, int]:
    text = SCENE.read_text().replace("<name>bellhop</name>", f"<name>bellhop</name>{extra}")
    scene = tmp_path / "scene.xml"
    scene.write_text(text)
    env = {"UWSIMNET_CACHE": str(tmp_path / "cache"), "PATH": "/usr/bin:/bin",
           "PYTHONPATH": str(Path(bellhop.__file__).resolve().parents[2])}
    p = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "validate", str(scene)], capture_output=True,
                       text=True, env=env, timeout=300)
    line = text[:text.index("<channelModel>\n")].count("\n") + 1
    return p, scene, line


def test_a_bellhop_that_runs_over_its_timeout_is_one_line(tmp_path):
    slow = tmp_path / "slow-bellhop"
    slow.write_text("#!/bin/sh\nexec sleep 60\n")
    slow.chmod(0o755)
    p, scene, line = _validate(tmp_path, f"<program>{slow}</program><timeout>0.5</timeout><workers>1</workers>")
    err = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(err) == 1 and "Traceback" not in p.stderr, p.stderr
    assert err[0].startswith(f"{scene}:{line}: ") and "ran over its timeout of 0.5 s" in err[0]
    assert not list((tmp_path / "cache").rglob("*.npz"))


def test_a_bellhop_that_fails_without_output_is_one_line(tmp_path):
    p, scene, line = _validate(tmp_path, "<program>/bin/false</program>")
    err = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(err) == 1 and "Traceback" not in p.stderr, p.stderr
    assert err[0].startswith(f"{scene}:{line}: ")
    assert err[0].endswith("Bellhop failed (/bin/false): exit status 1, no .shd and no .prt written")
    assert not list((tmp_path / "cache").rglob("*.npz"))
