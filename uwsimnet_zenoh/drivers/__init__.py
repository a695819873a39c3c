"""Real modem drivers and device emulators, grouped by device (docs/drivers.md).

* the driver port `registry`: names to driver and emulator plug-ins (built-ins, entry points of groups
  `uwsimnet.drivers` / `uwsimnet.emulators`) that `uwsimnet driver` and `uwsimnet emulate` read;
* `evologics/`: the EvoLogics S2C driver (TCP) and AT emulator; `dccomms/`: the dccomms serial radio driver
  and its pty emulator.  The formats they speak live below, in formats/;
* the driver SDK `base.Driver`; `zenoh_host`: a driver serving a modem id on Zenoh (HIL swap);
* `backend`: the modem backend interface emulators and bridges sit on; `sim_backend`: an in-process
  simulation as backends; `zenoh_backend`: a simulated modem of a running broker.
"""
