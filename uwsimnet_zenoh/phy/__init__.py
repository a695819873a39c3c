"""The physical layer: channel (air log, delays, collisions, carrier sense), modem (FIFO, timing, duplex),
the channel-model port (models.py, registry.py, testing.py: docs/channel-models.md) and its models (error.py
with expr.py, the BER expression language; acoustic.py: physics; ocean.py, ocean_model.py, bellhop.py: the
water, docs/ocean.md), interference.  Beside mac/ and never importing it: the modem calls its MAC through
`kernel.link.MacHooks` and offers it a `MacContext`.  Imports kernel/, trace/ and mobility/ only."""
