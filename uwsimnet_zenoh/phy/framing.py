"""The dccomms framings live in the format room (`formats/dccomms.py`, below phy and drivers); this name stays
for what still imports it from here (phy/modem.py, scene/, drivers/zenoh_backend.py)."""

from ..formats.dccomms import DEFAULT, Framing, FramingError, builder, known_builders

__all__ = ["DEFAULT", "Framing", "FramingError", "builder", "known_builders"]
