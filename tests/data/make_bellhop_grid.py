"""Make the Bellhop grid that tests/test_bellhop.py uses without Bellhop: the grid of
tests/data/ocean-shadow.xml's channel model, computed by the real program (`make bellhop`) through the model's
own code path, written to tests/data/bellhop/<content hash>-<Bellhop build tag>.npz.

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
net = Network(load_scene(HERE / "ocean-shadow.xml"))
for m in net.modems.values():
    print(m.id, m.error.path)
