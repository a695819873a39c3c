"""The faces: the one `uwsimnet` command (main.py builds the parser; drivers.py, deploy.py and
experiment.py add their sub-commands).  Imports any room; nothing imports it but the entry point."""

import gc

# The command's imports (numpy, pydantic and the scene models, the engine) make some 60 000 objects that live as
# long as the process; the cyclic garbage collector walked them ~85 times while they were made (~6 % of a short
# run).  So no collection during the import, then gc.freeze(): the collector never walks them again (reference
# counting still frees what is released; the few hundred objects of cyclic garbage the imports leave stay).
_collecting = gc.isenabled()
gc.disable()
try:
    from .main import main
finally:
    if _collecting:
        gc.freeze()
        gc.enable()

__all__ = ["main"]
