"""Real modem drivers, protocol cores and emulators (docs/drivers.md).

* sans-IO protocol cores: `evologics_at` (EvoLogics S2C AT commands, both ends), `dccomms_framing`
  (DataLinkFrame, CRC16 XMODEM, resynchronising decoder, GLI queue messages);
* the driver SDK `base.Driver` and two drivers: `evologics.EvoLogicsDriver` (TCP),
  `serial_radio.SerialRadioDriver` (serial device or pty);
* `backend`: the modem backend interface emulators and bridges sit on; `sim_backend`: an in-process
  simulation as backends;
* `emulators`: an EvoLogics AT TCP server and a framed serial pty backed by a simulated modem.
"""
