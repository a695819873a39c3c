"""The run functions: one assembly of Network + clock + trace sinks + summary, for the virtual clock
(virtual.py) and the realtime clock on Zenoh (realtime.py).  Below the faces (cli/, experiments/), above
everything else; imports zenoh only in realtime.py."""
