"""The faces: the one `uwsimnet` command (main.py builds the parser; drivers.py, deploy.py and
experiment.py add their sub-commands).  Imports any room; nothing imports it but the entry point."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
"""Before numpy loads: OpenBLAS would start a thread per core that spins ~0.1 s of a core after start-up
(and after every BLAS call) waiting for work.  The engine's arrays are one value per modem, never a matrix
worth a second thread.  The variable is inherited by what a command starts, as any setting of its
environment; set it yourself to have more."""

os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")
"""Before the scene's models are built: pydantic looks for its plugins (observers of validation, such as
logfire) by reading the entry points of every installed distribution, 20-30 ms of each start, and a scene
load has nothing for them to observe.  Inherited alike; set it yourself (empty: none disabled) to have
them."""

from .startup import importing  # noqa: E402 - after the variable

with importing():       # and each command imports what it runs the same way (start-up time)
    from .main import main


def command() -> int:
    """The `uwsimnet` console script: `main`, then everything it made frozen (gc.freeze) before Python exits.

    At exit, CPython collects every reference cycle left and frees its objects one by one; after a run, the
    metrics' per-frame state (one object a frame, in a cycle with the run) made that 0.15-0.2 s of a 1 s
    `uwsimnet run` (N = 256, 34 000 frames).  The process ends at once anyway and its memory goes with it.
    Nothing is lost: the commands close their own files and Zenoh sessions, never leaving that to the
    collector.  `main` itself freezes nothing, so tests can call it in their own process."""
    import gc

    code = main()
    gc.freeze()
    return code


__all__ = ["command", "main"]
