"""The Zenoh edge, above the sans-IO line: sessions and routers (session.py, router.py), the broker that
serves a Network's modems on the wire's keys (broker.py, control.py), the world clock, kinematic vehicles.
Imports the core rooms and uwsimnet_gli.wire; never the drivers, bridges, app or faces."""
