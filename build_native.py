"""Compile the engine's hot modules with mypyc (the list: uwsimnet_zenoh/_native.py), or say in one line why
not: the package then runs as pure Python, unchanged.  `make` runs this after installing the package and
before the tests; it does nothing when the build beside the sources matches them (_native.json).

    .venv/bin/python build_native.py            # build if stale; one line either way when it builds
    .venv/bin/python build_native.py --force    # try again after a failed build of the same sources
    .venv/bin/python build_native.py --clean    # remove the build (pure Python from then on)

A failed build is said once: the same sources are not tried again until one changes (or --force, `make clean`).
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.machinery
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
os.environ["UWSIMNET_PURE"] = "1"          # this process never loads the extensions it rebuilds

from uwsimnet_zenoh import _native  # noqa: E402

MYPY = "mypy==2.4.1"                       # mypyc comes with mypy; the version the build was measured with
BUILD = ROOT / "build" / "native"
LOG = BUILD / "build.log"
FAILED = BUILD / "failed.json"                  # the sources of the last failed build


def built_files() -> list[Path]:
    return [Path(_native.extension(m)) for m in (*_native.MODULES, _native.GROUP + "__mypyc")]


def clean() -> None:
    """Remove the build: the manifest and every extension in the package, the listed modules' and those of
    modules an older list compiled (left beside their sources, Python would import them)."""
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    for p in [Path(_native.MANIFEST), *built_files(), *Path(_native.PKG_DIR).rglob("*" + suffix)]:
        p.unlink(missing_ok=True)


def have_mypyc() -> bool:
    importlib.invalidate_caches()                   # after a pip install in this process
    try:
        import mypyc.build  # noqa: F401, PLC0415
    except ImportError:
        return False
    return True


def compile_all(log) -> None:
    """mypycify + build_ext --inplace, all output to `log`; raises on failure."""
    code = (
        "import sys\n"
        "from setuptools import setup\n"
        "from mypyc.build import mypycify\n"
        "files, cache, temp = sys.argv[1].split(','), sys.argv[2], sys.argv[3]\n"
        "setup(name='uwsimnet-zenoh-native', packages=[], py_modules=[],\n"
        "      ext_modules=mypycify(['--cache-dir', cache, '--follow-imports=silent', *files],\n"
        f"                           group_name={_native.GROUP!r}, target_dir=temp, opt_level='3'),\n"
        "      script_args=['build_ext', '--inplace', '--build-temp', temp])\n")
    files = ",".join(str(Path(_native.source(m)).relative_to(ROOT)) for m in _native.MODULES)
    env = {**os.environ, "UWSIMNET_PURE": "1"}
    subprocess.run([sys.executable, "-c", code, files, str(BUILD / "mypy_cache"), str(BUILD / "temp")],
                   cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env, check=True)


def main(argv: list[str]) -> int:
    if "--clean" in argv:
        clean()
        return 0
    if _native.stale_reason() is None:
        return 0                                    # up to date
    stats = _native.stats()                         # what is compiled (an edit during the build: stale)
    sources = _native.digests()
    if "--force" not in argv and FAILED.exists() and json.loads(FAILED.read_text()) == sources:
        return 0                                    # failed with these sources already: said then
    clean()                                         # a failed build leaves no extension behind
    FAILED.unlink(missing_ok=True)
    t0 = time.monotonic()
    print(f"uwsimnet: compiling {len(_native.MODULES)} engine modules with mypyc (about a minute, once; "
          "again only after one of them changes)", flush=True)
    BUILD.mkdir(parents=True, exist_ok=True)
    code = build()
    if code is not None:
        FAILED.write_text(json.dumps(sources))
        print(f"uwsimnet: the engine runs as pure Python ({code}; {LOG})")
        return 0
    Path(_native.MANIFEST).write_text(json.dumps(
        {"suffix": importlib.machinery.EXTENSION_SUFFIXES[0], "mypy": MYPY, "modules": sources,
         "stat": stats}, indent=1) + "\n")
    print(f"uwsimnet: compiled {len(_native.MODULES)} engine modules with mypyc in {time.monotonic() - t0:.0f} s")
    return 0


def build() -> str | None:
    """Build the extensions; None when done, else why not (and nothing built is left behind)."""
    with open(LOG, "w") as log:
        if not have_mypyc():
            r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", MYPY], stdout=log, stderr=log)
            if r.returncode != 0 or not have_mypyc():
                return f"{MYPY} could not be installed"
        try:
            compile_all(log)
        except (subprocess.CalledProcessError, OSError) as e:
            with contextlib.suppress(OSError):
                clean()
            return f"the mypyc build failed: {type(e).__name__}"
    missing = [p.name for p in built_files() if not p.exists()]
    if missing:
        clean()
        return f"the build made no {missing[0]}"
    return None


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
