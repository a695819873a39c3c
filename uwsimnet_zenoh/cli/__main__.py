"""`python -m uwsimnet_zenoh.cli ...` is `uwsimnet ...`."""

import sys

from . import command

sys.exit(command())
