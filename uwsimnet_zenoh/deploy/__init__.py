"""Lab deployment: an inventory (TOML) rendered into per-machine Zenoh router and client configurations,
TLS certificate commands and access-control rules whose key expressions come from the one wire
(uwsimnet_gli.wire).  Beside bus/ (never imports it); the CLI face is `uwsimnet deploy`."""
