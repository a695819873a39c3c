"""uwsimnet_gli: what an application links to talk to uwsimnet-zenoh modems (simulated or real).

Only eclipse-zenoh and msgpack: no simulator import.  The wire protocol is docs/gli-protocol.md.

    from uwsimnet_gli import World, Modem

    with World("acoustic-apps") as world:            # client of the router at tcp/127.0.0.1:7447
        alpha = Modem(world, "alpha-modem")
        alpha.wait_kind(timeout=5)
        tag = alpha.send(2, b"hello")
        print(alpha.wait_status(tag))
        for frame in alpha.frames(timeout=10):
            print(frame.src, frame.data, frame.t_rx)
"""

from uwsimnet_gli.modem import Modem
from uwsimnet_gli.world import GliError, World, client_config, discover_worlds, load_config

from .records import Frame, Status
from .wire import BROADCAST, DEFAULT_ENDPOINT

__all__ = ["BROADCAST", "DEFAULT_ENDPOINT", "Frame", "GliError", "Modem", "Status", "World", "client_config",
           "discover_worlds", "load_config"]
__version__ = "0.1.0"
