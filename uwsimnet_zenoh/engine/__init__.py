"""The wiring: `Network` (a scene's pose table, channels, modems, flows on one scheduler) and the build step
(build.py) that makes each modem with its loss model and its MAC.  Top of the core: imports every core room
below it, never zenoh or anything above the sans-IO line."""

from .network import Network

__all__ = ["Network"]
