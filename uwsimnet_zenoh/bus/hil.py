"""The HIL swap as a small state machine (no I/O, no Zenoh): who serves each modem id, the simulator or a
real driver, and what the broker must do when a real driver's `driver/real` token comes or goes.

    swap = HilSwap()
    swap.driver_up("bravo-m", served=True)        -> SWAP_OUT   (take the simulated modem off the channel)
    swap.swapped_out("bravo-m", vehicle, cfg)     (remember how to put it back)
    swap.driver_down("bravo-m", in_network=False) -> (SWAP_IN, (vehicle, cfg))   (re-add it from the scene)
    swap.driver_down(...) for an id never swapped -> (RETOKEN, None) or (NOTHING, None)

The broker (bus/broker.py) turns the actions into effects: undeclaring/declaring the `driver/sim` token,
draining the modem's FIFO with reason `swapped`, removing/re-adding the device.
"""

from __future__ import annotations

from typing import Any

NOTHING = "nothing"
SWAP_OUT = "swap_out"
SWAP_IN = "swap_in"
RETOKEN = "retoken"


class HilSwap:
    def __init__(self) -> None:
        self.real: set[str] = set()
        """Modem ids for which a real driver holds `driver/real`."""
        self.held: dict[str, tuple[str, Any]] = {}
        """Modems handed to a real driver: (vehicle, device config) to put them back when it leaves."""

    def driver_up(self, dev: str, served: bool) -> str:
        """A `driver/real` token appeared for `dev`; `served`: the simulator serves it right now."""
        if dev in self.real:
            return NOTHING
        self.real.add(dev)
        return SWAP_OUT if served else NOTHING

    def swapped_out(self, dev: str, vehicle: str, cfg: Any) -> None:
        self.held[dev] = (vehicle, cfg)

    def driver_down(self, dev: str, in_network: bool) -> tuple[str, tuple[str, Any] | None]:
        """The token of `dev` went away; `in_network`: a simulated modem of that id exists (it was never
        swapped out, e.g. the driver came before the broker served it)."""
        if dev not in self.real:
            return NOTHING, None
        self.real.discard(dev)
        held = self.held.pop(dev, None)
        if held is not None and not in_network:
            return SWAP_IN, held
        return RETOKEN, None
