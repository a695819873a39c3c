"""A run assembled, above the sans-IO core and below the Zenoh rooms: its outputs (outputs.py: the trace
writer, the tracing plug-in, the online metrics on the output port), one assembly for `uwsimnet run` (app/:
the virtual and the realtime clock) and the simulator backend (drivers/sim_backend.py).  Opens files, never
Zenoh.  Imports engine/, analysis/, trace/ and errors only."""
