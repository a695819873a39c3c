"""A group of child processes for multi-process experiments: each started with its output in a log file,
waited for until it prints its ready line, stopped with SIGTERM in reverse order, its exit code checked."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from ..errors import UwsimnetError

PY = sys.executable


class ProcessError(UwsimnetError, RuntimeError):
    pass


class Proc:
    def __init__(self, name: str, argv: list[str], log: Path) -> None:
        self.name = name
        self.argv = argv
        self.log = log
        self._fh = open(log, "w")  # noqa: SIM115 - closed in stop()
        self.p = subprocess.Popen(argv, stdout=self._fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True)

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def tail(self, n: int = 15) -> str:
        return "\n".join(f"    {line}" for line in self.output().splitlines()[-n:])

    def wait_ready(self, line: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while line not in self.output():
            if self.p.poll() is not None:
                raise ProcessError(f"{self.name} exited with {self.p.returncode} before it was ready:\n"
                                   f"{self.tail()}")
            if time.monotonic() > deadline:
                raise ProcessError(f"{self.name} not ready after {timeout:g} s:\n{self.tail()}")
            time.sleep(0.05)

    def stop(self, timeout: float = 15.0) -> int:
        if self.p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self._fh.close()
        return self.p.returncode


class Processes:
    """    with Processes(log_dir) as procs:
               procs.start("router", [...], ready="listening on")
    Leaving the block stops them all (last started first); `stop_all()` says which did not exit 0."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        log_dir.mkdir(parents=True, exist_ok=True)
        self.procs: list[Proc] = []

    def start(self, name: str, argv: list[str], *, ready: str, timeout: float = 30.0) -> Proc:
        p = Proc(name, argv, self.log_dir / f"{name}.log")
        self.procs.append(p)
        p.wait_ready(ready, timeout)
        return p

    def check_alive(self) -> None:
        for p in self.procs:
            if p.p.poll() is not None:
                raise ProcessError(f"{p.name} exited early with {p.p.returncode}:\n{p.tail()}")

    def stop_all(self) -> list[str]:
        """Stop every process (SIGTERM, last started first); the failures, one text each."""
        bad = []
        for p in reversed(self.procs):
            rc = p.stop()
            if rc != 0:
                bad.append(f"{p.name} exited with {rc} (log {p.log}):\n{p.tail()}")
        self.procs = []
        return bad

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()
