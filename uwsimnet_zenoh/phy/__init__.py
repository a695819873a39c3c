"""The physical layer: channel (air log, delays, collisions, carrier sense), modem (FIFO, timing, duplex),
loss models (error.py, expr.py: the BER expression language; acoustic.py: physics), interference.  Beside
mac/ and never importing it: the modem calls its MAC through `kernel.link.MacHooks` and is its `MacContext`.
Imports kernel/, trace/ and mobility/ only."""
