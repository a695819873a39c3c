"""Device formats, sans-IO and written once: the dccomms framings and GLI queue messages (`dccomms`), their
resynchronising stream decoder (`dccomms_stream`), the EvoLogics S2C AT command set, both ends
(`evologics_at`).  Below phy and drivers: the PHY counts framed sizes on air, scenes name packet builders,
drivers, emulators and bridges speak the formats.  Imports errors/ only."""
