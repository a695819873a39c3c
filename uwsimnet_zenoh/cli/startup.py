"""The command's start-up: its imports without cyclic garbage collection (`importing`)."""

from __future__ import annotations

import gc
import sys
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def importing() -> Iterator[None]:
    """Imports without cyclic garbage collection, then gc.freeze() if they loaded modules.

    The imports of a run (numpy, pydantic and the scene models, the engine) make ~60 000 objects that live as long
    as the process; the collector walked them ~85 times while they were made, 5-7 % of a short run.  Frozen, they
    are never walked again (reference counting still frees what is released; the few hundred objects of cyclic
    garbage the imports leave stay).  Raising the collector's thresholds instead does not help: the cost is per
    object walked, not per collection."""
    if not gc.isenabled():
        yield
        return
    loaded = len(sys.modules)
    gc.disable()
    try:
        yield
    finally:
        if len(sys.modules) != loaded:
            gc.freeze()
        gc.enable()
