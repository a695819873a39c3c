"""The paper's experiments and reference scenarios, runnable as `python -m uwsimnet_zenoh.experiments`."""
