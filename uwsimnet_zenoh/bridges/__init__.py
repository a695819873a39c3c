"""Bridges for applications that cannot link Zenoh (docs/bridges.md).

* `socket_bridge`: a modem on a TCP/UDP socket, length-prefixed binary messages (`socket_wire`; any
  language; see gli_clients/c/gli_socket_client.c; `socket_client` is a blocking Python client).
* `mq_bridge`: the dccomms GLI's POSIX message queues (`/<id>_tx_dlnk_phy`, `/<id>_rx_dlnk_phy`), so
  existing dccomms applications run unmodified.

Both sit on a `drivers.backend.ModemBackend`, like the emulators: an in-process simulated modem
(`drivers.sim_backend`) or a modem served by a broker over Zenoh (`drivers.zenoh_backend`).  Above drivers/,
below app/.
"""
