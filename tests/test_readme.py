"""README.md's commands, in order, as written (run from the repository root), on fresh ports: each one
does what the README says and prints what it should (issue #20).

The only change to a command is the port: `uwsimnet run` gets `--listen tcp/127.0.0.1:<free port>` and
`gli` gets `-e` for it, as the README says to do when 7447 is taken (the test must not depend on 7447
being free).  Commands ending in `&` run in the background, as in a shell."""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()

pytest.importorskip("uwsimnet_gli")


def section(title: str) -> str:
    start = README.index(f"## {title}")
    end = README.find("\n## ", start + 1)
    return README[start:end if end > 0 else None]


def commands(text: str) -> list[tuple[list[str], bool]]:
    """(argv, background) of every line of the sh blocks of `text`, comments removed."""
    out = []
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        block = re.sub(r"\\\n\s*", " ", re.sub(r"\s{2,}#[^\n]*\\\n", " \\\n", block))   # continuation lines
        for line in block.splitlines():
            line = re.split(r"\s{2,}#|^#", line)[0].strip()
            if not line:
                continue
            bg = line.endswith("&")
            out.append((shlex.split(line.rstrip("&")), bg))
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Bg:
    """A background command whose output is collected by threads."""

    def __init__(self, argv: list[str]) -> None:
        self.p = subprocess.Popen(argv, cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self.out: list[str] = []
        self.err: list[str] = []
        self.readers = [threading.Thread(target=lambda fh=fh, dst=dst: dst.extend(iter(fh.readline, "")), daemon=True)
                        for fh, dst in ((self.p.stdout, self.out), (self.p.stderr, self.err))]
        for t in self.readers:
            t.start()

    def drained(self, timeout: float = 10.0) -> None:
        """Wait until the reader threads have read everything the exited process wrote."""
        for t in self.readers:
            t.join(timeout)

    def text(self) -> str:
        return "".join(self.out) + "\n--- stderr ---\n" + "".join(self.err)

    def wait_for(self, pattern: str, timeout: float, stream: str = "out") -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = re.search(pattern, "".join(self.out if stream == "out" else self.err), re.M)
            if m:
                return m.group(0)
            if self.p.poll() is not None:
                self.drained()                          # exited: everything it wrote, then one last look
                if re.search(pattern, "".join(self.out if stream == "out" else self.err), re.M):
                    continue
                break
            time.sleep(0.05)
        raise AssertionError(f"{self.p.args}: no {pattern!r} within {timeout} s\n{self.text()}")

    def stop(self) -> int:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
            try:
                self.p.wait(30)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self.drained()
        return self.p.returncode


def run(argv: list[str], timeout: float = 120, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def workdir(tmp: Path) -> Path:
    """A folder that looks like the repository's top to the README's commands (its .venv, scenes and examples
    linked), so what they write (out/) lands there and never in a user's out/."""
    for name in (".venv", "scenes", "examples"):
        (tmp / name).symlink_to(ROOT / name)
    return tmp


def test_readme_commands_block(tmp_path):
    cmds = commands(section("Commands"))
    assert [argv[1] for argv, _ in cmds][:4] == ["validate", "run", "report", "plot"]
    cmds = cmds[:4]                 # (then `uwsimnet sweep`: test_readme_sweep_compares_macs_at_rates_they_carry)
    outs = []
    cwd = workdir(tmp_path)
    for argv, bg in cmds:
        assert not bg and Path(ROOT / argv[0]).exists(), argv
        r = run(argv, cwd=cwd)
        assert r.returncode == 0, (argv, r.stdout, r.stderr)
        assert "Traceback" not in r.stderr
        outs.append(r.stdout)
    assert outs[0].startswith("scenes/paper/phy-layer-rf.xml: ok (")
    assert "rov0-to-rov1" in outs[1] and "trace: out/rf.jsonl" in outs[1]
    assert "rov0-to-rov1" in outs[2] and "thr B/s" in outs[2]
    figs = [ln for ln in outs[3].splitlines() if ln.endswith(".png")]
    assert figs and all((cwd / f).is_file() for f in figs)
    assert (cwd / "out" / "rf.jsonl").is_file()


def test_readme_sweep_compares_macs_at_rates_they_carry(tmp_path):
    """The README's campaign, as written: each MAC at rates it carries (at least 95 % of what the RF flows
    offer arrives, next to nothing is left in or refused by the FIFO), delay drawn on a log axis."""
    (argv, bg), = [c for c in commands(section("Commands")) if c[0][1] == "sweep"]
    cwd = workdir(tmp_path)
    r = run(argv, timeout=600, cwd=cwd)
    assert r.returncode == 0 and not bg and "Traceback" not in r.stderr, r.stderr
    assert "### frames left in the FIFO at the end" in r.stdout and "### frames dropped at a full FIFO" in r.stdout
    summary = json.loads((cwd / "out" / "sweep" / "summary.json").read_text())
    assert sorted(summary) == ["twinbot-aloha", "twinbot-sfama"]
    for mac, s in summary.items():
        assert {m["n"] for m in s.values() if m is not None} == {5}, mac
        for flow in ("leader", "follower"):
            enq = s[f"flow.{flow}.enqueued"]["mean"]
            assert s[f"flow.{flow}.throughput"]["mean"] >= 0.95 * s[f"flow.{flow}.offered"]["mean"], (mac, flow)
            assert s[f"flow.{flow}.fifo_drops"]["mean"] == 0, (mac, flow)
            assert s[f"flow.{flow}.left_in_fifo"]["mean"] <= 0.02 * enq, (mac, flow)
    assert "log axis" in section("Commands") and (cwd / "out" / "sweep" / "figures" / "delay_mean.png").is_file()


def test_readme_real_time_block_in_order_on_fresh_ports(tmp_path):
    cmds = commands(section("Real time, your own apps, real modems"))
    names = [" ".join(a[:2]) if "gli" not in a[0] else f"gli {a[a.index('acoustic-apps') + 1]}" for a, _ in cmds]
    assert names == [".venv/bin/python examples/acoustic_demo.py", ".venv/bin/uwsimnet run", "gli pose",
                     "gli listen", "gli send"], names
    demo, sim, pose, listen, send = (a for a, _ in cmds)
    assert [bg for _, bg in cmds] == [False, False, False, True, False]

    # 1. the demo, on a port of its own
    r = run(demo, timeout=120, cwd=workdir(tmp_path))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert re.search(r"^\[demo\] simulator on tcp/127\.0\.0\.1:\d+; starting the apps$", r.stdout, re.M)
    assert re.search(r"^\[pong\] pong_app: got 'ping \d+' from 1, one-way delay", r.stdout, re.M)
    assert re.search(r"^\[ping\] ping_app: 'pong \d+' from 2, round trip", r.stdout, re.M)
    assert "[demo] exit codes {'uwsimnet': 0, 'pong': 0, 'ping': 0}; trace out/acoustic-apps.jsonl" in r.stdout

    # 2. the simulator by hand (terminal 1), on a fresh port
    ep = f"tcp/127.0.0.1:{free_port()}"
    s = Bg([*sim, "--listen", ep])
    try:
        s.wait_for(r"^uwsimnet: running for 600 s \(realtime clock\)", 30)      # the scene's duration
        assert f"uwsimnet: listening on {ep}" in s.text()

        def gli(argv: list[str]) -> list[str]:
            return [argv[0], "-e", ep, *argv[1:]]
        p = run(gli(pose), timeout=60)                                      # 3. bravo placed from outside
        assert p.returncode == 0 and p.stdout.startswith("Putting pose (100.0, 0.0, -10.0)"), p.stdout + p.stderr
        li = Bg(gli(listen))                                               # 4. in the background
        li.wait_for(r"^Press CTRL-C to quit", 30, stream="err")
        # 5. from the shell; a frame put before the listener's subscription reached the router is routed to
        # nobody, so the send is repeated (each as written) until the listener has one (--count 1: it exits)
        deadline = time.monotonic() + 60
        while True:
            sd = run(gli(send), timeout=60)
            assert sd.returncode == 0, sd.stdout + sd.stderr
            assert re.search(r"^Sending to 2 \(tag \d+, 5 B\): 'hello'$", sd.stdout, re.M), sd.stdout
            assert re.search(r"^  sent at t=\d+\.\d{6}$", sd.stdout, re.M), sd.stdout
            try:
                li.p.wait(5)                                               # the frame's time on air, amply
                break
            except subprocess.TimeoutExpired:
                assert time.monotonic() < deadline, li.text()
        li.drained()
        assert li.p.returncode == 0, li.text()
        assert re.search(r"^>> \[rx\] bravo-modem <- 1 \(dst 2, seq \d+\) t_tx=\S+ t_rx=\S+: 'hello'$",
                         "".join(li.out), re.M), li.text()
    finally:
        rc = s.stop()
    assert rc == 0, s.text()
    out = s.text()
    assert "uwsimnet: stopping (SIGINT)" in out and "alpha-modem" in out.split("stopping", 1)[1]
    assert "Traceback" not in out


def test_readme_says_what_to_do_when_7447_is_taken():
    """The README's advice holds: on a taken port `uwsimnet run` names it in one line and exits 2."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r = run([".venv/bin/uwsimnet", "run", "scenes/examples/acoustic-apps.xml", "--clock", "realtime",
                 "--listen", f"tcp/127.0.0.1:{port}"], timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"cannot listen on tcp/127.0.0.1:{port}" in r.stderr and "--listen another endpoint" in r.stderr
    assert "one line and exits 2" in section("Real time, your own apps, real modems")
