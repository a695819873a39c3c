"""The faces: the one `uwsimnet` command (main.py builds the parser; drivers.py, deploy.py and
experiment.py add their sub-commands).  Imports any room; nothing imports it but the entry point."""

from .startup import importing

with importing():       # and each command imports what it runs the same way (start-up time)
    from .main import main

__all__ = ["main"]
