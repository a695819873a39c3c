"""`python -m uwsimnet_zenoh.cli ...` is `uwsimnet ...`."""

import sys

from .main import main

sys.exit(main())
