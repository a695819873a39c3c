"""bravo's application: answers every ping with a pong, and drives bravo by publishing its pose.

    python examples/pong_app.py [-e tcp/127.0.0.1:7447] [--speed 40] [--duration S]

bravo has poseSource zenoh in scenes/examples/acoustic-apps.xml: the simulator knows where it is only
from what this app publishes on uwsimnet/acoustic-apps/pose/bravo (10 Hz, with its velocity).  It goes
out from 100 m to 850 m and back, so the acoustic delay grows and shrinks, the link degrades past 400 m
and breaks past 800 m.  Only uwsimnet_gli (zenoh + msgpack) is needed.
"""

from __future__ import annotations

import argparse
import threading
import time

from uwsimnet_gli import Frame, World

NEAR, FAR = 100.0, 850.0


def position(t: float, speed: float) -> tuple[float, float]:
    """x and vx of a back-and-forth run between NEAR and FAR at `speed` m/s."""
    span = FAR - NEAR
    d = (t * speed) % (2 * span)
    return (NEAR + d, speed) if d < span else (FAR - (d - span), -speed)


def drive(world: World, speed: float, stop: threading.Event) -> None:
    t0 = time.monotonic()
    while not stop.is_set():
        x, vx = position(time.monotonic() - t0, speed)
        world.publish_pose("bravo", (x, 0.0, 10.0), v=(vx, 0.0, 0.0))
        stop.wait(0.1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-e", "--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--speed", type=float, default=60.0, help="m/s (fast, to see the effect in seconds)")
    ap.add_argument("--duration", type=float, help="s (default: until Ctrl-C)")
    a = ap.parse_args()
    stop = threading.Event()
    with World("acoustic-apps", connect=a.connect) as world:
        bravo = world.modem("bravo-modem")
        print(f"bravo-modem served by: {bravo.wait_kind(timeout=10)}", flush=True)
        driver = threading.Thread(target=drive, args=(world, a.speed, stop), daemon=True)
        driver.start()

        @bravo.on_receive
        def answer(f: Frame) -> None:      # runs on a Zenoh thread: just send (it only enqueues)
            bravo.send(f.src, b"pong " + f.data[5:])

        t_end = None if a.duration is None else time.monotonic() + a.duration
        try:
            while t_end is None or time.monotonic() < t_end:
                f = bravo.receive(timeout=0.5)
                if f is not None:
                    x = bravo.info(timeout=1.0) or {}
                    pos = x.get("position") or [float("nan")]
                    print(f"pong_app: got {f.data.decode(errors='replace')!r} from {f.src}, one-way delay"
                          f" {(f.t_rx - f.t_tx) * 1e3:.1f} ms, bravo at x={pos[0]:.0f} m", flush=True)
        except KeyboardInterrupt:
            pass
        finally:
            stop.set()
            driver.join(1.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
