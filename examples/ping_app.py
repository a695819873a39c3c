"""alpha's application: pings bravo (address 2) once a second and reports what comes back.

    python examples/ping_app.py [-e tcp/127.0.0.1:7447] [--count N] [--interval S]

For every ping it prints the modem's status (sent, or dropped with a reason such as `nopose` while
bravo has no pose yet) and the round trip in simulation time when the pong arrives.  Only uwsimnet_gli
(zenoh + msgpack) is needed; run it next to `uwsimnet run scenes/examples/acoustic-apps.xml` and
examples/pong_app.py.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib

from uwsimnet_gli import World


async def run(world: World, count: int | None, interval: float) -> None:
    alpha = world.modem("alpha-modem")
    print(f"alpha-modem served by: {alpha.wait_kind(timeout=10)}", flush=True)
    sent_at: dict[int, float] = {}

    async def pongs() -> None:                       # the asyncio side of the client
        async for f in alpha.aframes():
            n = int(f.data.split()[-1]) if f.data.startswith(b"pong") else -1
            t0 = sent_at.pop(n, None)
            rtt = f"{(f.t_rx - t0) * 1e3:.1f} ms" if t0 is not None else "?"
            print(f"ping_app: {f.data.decode(errors='replace')!r} from {f.src}, round trip {rtt}", flush=True)

    task = asyncio.create_task(pongs())
    n = 0
    try:
        while count is None or n < count:
            tag = alpha.send(2, f"ping {n}".encode())
            st = await asyncio.to_thread(alpha.wait_status, tag, timeout=5.0)
            if st is None:
                print(f"ping_app: ping {n}: no status", flush=True)
            elif st.event in ("sent", "acked"):
                # the round trip counts from when the modem accepted the ping (its `queued` status)
                sent_at[n] = next((s.t for s in alpha.statuses(tag) if s.event == "queued"), st.t)
                print(f"ping_app: ping {n} sent at t={sent_at[n]:.3f} s", flush=True)
            else:
                print(f"ping_app: ping {n} {st.event} ({st.reason})", flush=True)
            n += 1
            await asyncio.sleep(interval)
        await asyncio.sleep(2.0)                     # the last pong may still be on its way
    finally:
        task.cancel()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-e", "--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--count", type=int, help="pings (default: until Ctrl-C)")
    ap.add_argument("--interval", type=float, default=1.0)
    a = ap.parse_args()
    with World("acoustic-apps", connect=a.connect) as world, contextlib.suppress(KeyboardInterrupt):
        asyncio.run(run(world, a.count, a.interval))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
