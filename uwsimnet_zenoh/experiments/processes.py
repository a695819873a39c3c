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


class Progress:
    """Progress of a long run: a rich bar on a terminal; plain lines when the output is piped or
    redirected (a bar would print nothing there), one every `every` s of wall time and at the end.

        with Progress("HIL formation, real time", total=240) as bar:
            bar.update(done)
    """

    def __init__(self, label: str, total: float, *, stream=None, every: float = 10.0, unit: str = "s") -> None:
        self.label, self.total, self.every, self.unit = label, total, every, unit
        self.stream = stream if stream is not None else sys.stdout
        self.done = 0.0
        self._bar = None
        self._task = None
        self._last = -float("inf")
        self._shown: float | None = None

    def __enter__(self) -> Progress:
        isatty = getattr(self.stream, "isatty", None)
        if isatty is not None and isatty():
            from rich.console import Console  # noqa: PLC0415 - rich only for a terminal
            from rich.progress import Progress as Bar  # noqa: PLC0415

            self._bar = Bar(transient=True, console=Console(file=self.stream))
            self._bar.__enter__()
            self._task = self._bar.add_task(self.label, total=self.total)
        else:
            self._line()
        return self

    def _line(self) -> None:
        self._last = time.monotonic()
        self._shown = self.done
        pct = 100.0 * self.done / self.total if self.total else 100.0
        print(f"{self.label}: {self.done:.0f}/{self.total:g} {self.unit} ({pct:.0f}%)", file=self.stream,
              flush=True)

    def update(self, done: float) -> None:
        self.done = min(float(done), self.total)
        if self._bar is not None:
            self._bar.update(self._task, completed=self.done)
        elif time.monotonic() - self._last >= self.every:
            self._line()

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.__exit__(*exc)
        elif exc[0] is None and self.done != self._shown:
            self._line()
