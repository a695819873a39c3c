"""Broker memory over a realtime soak (issue #41): is the resident set flat while frames keep coming?

`uwsimnet run --clock realtime` is started as a process on a scene of 64 modems 100 m apart on a line, each
sending a 16 B frame to its neighbour once a second (64 frames/s in all, staggered by 1/64 s); nothing
else runs.  Every `--every` seconds the broker's RSS is read from /proc/PID/status (VmRSS).  Reported: the
RSS at 1, 5 and 10 minutes (or the ends of a shorter run), and the slope of a least-squares line through
the samples after the first minute (start-up, Zenoh's buffers and the import of everything are done by
then), in MB per minute.  A slope that stays at 0.8 MB/min is 235 B a frame; flat is a few kB/min.

`--pose-names N`: also, during the first minute, N pose samples each naming a vehicle nobody has (a forged
flood of names): the broker must count them (`pose_unknown` in its summary) and keep no state per name.

Run: .venv/bin/python bench/bench_soak.py --minutes 10 [--code DIR] [--modems 64] [--every 5] [--json F]
[--pose-names N]
`--code DIR`: the uwsimnet_zenoh package to run (a checkout, e.g. `git archive main | tar -x -C DIR`),
by default this one.  Any flag the run takes can follow `--`, e.g. `-- --trace /tmp/soak.jsonl`.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def scene_xml(n: int, world: str, minutes: float) -> str:
    """n modems on a line, 100 m apart (150 m reach: each hears its neighbours), no errors, each sending
    one 16 B frame a second to the next one (the last to the previous): n frames/s, evenly staggered."""
    vs, flows = [], []
    for i in range(n):
        vs.append(f"""<vehicle><name>v{i}</name><position>{100 * i} 0 10</position><CustomCommsDevice>
<dccommsId>m{i}</dccommsId><mac>{i + 1}</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>
<bitrate>100000</bitrate><txFifoSize>100000</txFifoSize><intrinsicDelay>0</intrinsicDelay>
<maxDistance>150</maxDistance><rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr>
</rateErrorModel></CustomCommsDevice></vehicle>""")
        dst = i + 2 if i + 1 < n else i
        flows.append(f"<flow><name>f{i}</name><src>m{i}</src><dst>{dst}</dst><size>16</size><interval>1</interval>"
                     f"<arrival>periodic</arrival><start>{i / n:.6f}</start></flow>")
    return f"""<?xml version="1.0"?><UWSimScene><simulation><seed>1</seed><clock>realtime</clock>
<duration>{minutes * 60 + 30:.0f}</duration><world>{world}</world></simulation>
<CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
{''.join(vs)}{''.join(flows)}</UWSimScene>"""


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for {pid}")


def slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of ys over xs."""
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx if sxx else float("nan")


def at(samples: list[tuple[float, float]], minute: float) -> float:
    """The RSS of the sample nearest `minute`."""
    return min(samples, key=lambda s: abs(s[0] - minute * 60))[1]


def flood_names(endpoint: str, world: str, names: int, seconds: float) -> None:
    """`names` pose samples, each for a vehicle of its own that the scene does not have, over `seconds`."""
    import zenoh  # noqa: PLC0415 - only this mode needs a session here
    from uwsimnet_gli.wire import Keys, encode_pose  # noqa: PLC0415

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    keys = Keys(world)
    with zenoh.open(conf) as s:
        t0 = time.monotonic()
        for i in range(names):
            s.put(keys.pose(f"forged{i}"), encode_pose((0.0, 0.0, 0.0)))
            d = t0 + seconds * (i + 1) / names - time.monotonic()
            if d > 0:
                time.sleep(d)


def soak(minutes: float, n: int, every: float, code: Path, extra: list[str], pose_names: int = 0) -> dict:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "soak.xml"
        path.write_text(scene_xml(n, "soak", minutes))
        env = dict(os.environ, PYTHONPATH=str(code))
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        argv = [sys.executable, "-m", "uwsimnet_zenoh.cli", "run", str(path), "--clock", "realtime",
                "--listen", endpoint, *extra]
        p = subprocess.Popen(argv, cwd=d, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert p.stdout is not None
        for line in p.stdout:                       # wait for the run to start
            if line.startswith("uwsimnet: running"):
                break
        else:
            raise RuntimeError(f"the broker did not start (exit {p.wait()})")
        t0 = time.monotonic()
        if pose_names:
            import threading  # noqa: PLC0415
            threading.Thread(target=flood_names, args=(endpoint, "soak", pose_names, min(60.0, minutes * 30)),
                             daemon=True).start()
        samples: list[tuple[float, float]] = []
        load0 = os.getloadavg()[0]
        try:
            while (t := time.monotonic() - t0) <= minutes * 60 and p.poll() is None:
                samples.append((t, rss_mb(p.pid)))
                time.sleep(max(0.0, every - (time.monotonic() - t0 - t)))
        finally:
            p.send_signal(signal.SIGINT)
            out = p.communicate(timeout=120)[0]
        load1 = os.getloadavg()[0]
    late = [s for s in samples if s[0] >= 60] or samples
    return {"machine": f"{platform.node()} {platform.machine()} {os.cpu_count()} cores",
            "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "load": f"{load0:.1f}-{load1:.1f}", "code": str(code), "modems": n, "minutes": minutes,
            "pose_names": pose_names,
            "rss_1": at(samples, 1), "rss_5": at(samples, min(5, minutes)), "rss_10": at(samples, min(10, minutes)),
            "slope_mb_per_min": 60 * slope([s[0] for s in late], [s[1] for s in late]),
            "samples": samples, "summary_tail": [x for x in out.strip().splitlines()[-8:] if not x.startswith("f")]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--modems", type=int, default=64)
    ap.add_argument("--every", type=float, default=5.0, help="seconds between RSS samples")
    ap.add_argument("--code", type=Path, default=ROOT, help="directory holding the uwsimnet_zenoh to run")
    ap.add_argument("--json", type=Path, help="write the result (with every sample) here")
    ap.add_argument("--pose-names", type=int, default=0, help="forged pose names to send in the first minute")
    ap.add_argument("extra", nargs="*", help="flags for `uwsimnet run` (after --)")
    a = ap.parse_args()
    r = soak(a.minutes, a.modems, a.every, a.code.resolve(), a.extra, a.pose_names)
    if a.json:
        a.json.write_text(json.dumps(r, indent=1))
    print("| machine | date | load | code | MB at 1 min | 5 min | 10 min | slope after 1 min (MB/min) |")
    print(f"| {r['machine']} | {r['date']} | {r['load']} | {r['code']} | {r['rss_1']:.1f} | {r['rss_5']:.1f} "
          f"| {r['rss_10']:.1f} | {r['slope_mb_per_min']:+.3f} |")
    print("\n".join(r["summary_tail"]))


if __name__ == "__main__":
    main()
