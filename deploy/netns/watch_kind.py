"""Print `<wall time> <kind>` each time a modem's kind changes (sim, real, None), for DURATION seconds.

    python watch_kind.py CONFIG|- ENDPOINT WORLD MODEM DURATION      (used by run-scene.sh FAULT=linkcut)

CONFIG: a Zenoh client configuration file (TLS login), or - for a plain client of ENDPOINT.
"""

from __future__ import annotations

import sys
import time

from uwsimnet_gli import World, load_config


def main() -> int:
    config, endpoint, world, modem = sys.argv[1:5]
    duration = float(sys.argv[5])
    conf = load_config(config) if config != "-" else load_config(None, endpoint)
    with World(world, config=conf) as w:
        m = w.modem(modem)
        m.on_kind(lambda k: print(f"{time.time():.3f} {k}", flush=True))
        print(f"{time.time():.3f} {m.wait_kind(timeout=10)} (start)", flush=True)
        time.sleep(duration)
    return 0


if __name__ == "__main__":
    sys.exit(main())
