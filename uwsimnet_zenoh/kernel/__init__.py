"""The bottom room: time and the thing that travels.

`Scheduler` (a heap of timed callbacks, the virtual clock), `RealtimeClock` (the same scheduler against the
wall clock, on its own thread), `Frame`, and the contract between a modem and its MAC (`link`).  Imports nothing
of the project; every other room may import it.
"""

from .frame import BROADCAST, Frame
from .scheduler import Event, Scheduler

__all__ = ["BROADCAST", "Event", "Frame", "Scheduler"]
