"""Make the Bellhop grids that the tests use without Bellhop: the grids of tests/data/ocean-shadow.xml's channel
model (tests/test_bellhop.py) and of scenes/examples/twinbot-thermocline.xml's (tests/test_twinbot_ocean.py),
computed by the real program (`make bellhop`) through the model's own code path, written to
tests/data/bellhop/ and tests/data/twinbot-ocean/bellhop/ as <content hash>-<Bellhop build tag>.npz.

    UWSIMNET_CACHE=tests/data .venv/bin/python tests/data/make_bellhop_grid.py
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
os.environ["UWSIMNET_CACHE"] = str(HERE)

from uwsimnet_zenoh.engine.network import Network  # noqa: E402
from uwsimnet_zenoh.phy.bellhop import find_program  # noqa: E402
from uwsimnet_zenoh.scene import load_scene  # noqa: E402

if find_program() is None:
    sys.exit("Bellhop not found: run `make bellhop` first")
for scene, cache in ((HERE / "ocean-shadow.xml", HERE),
                     (HERE.parents[1] / "scenes" / "examples" / "twinbot-thermocline.xml", HERE / "twinbot-ocean")):
    os.environ["UWSIMNET_CACHE"] = str(cache)
    net = Network(load_scene(scene))
    for m in net.modems.values():
        print(m.id, m.error.path)
