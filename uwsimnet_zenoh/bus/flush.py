"""What this process has written to its TCP peers that they have not taken yet, and a bounded wait for it.

A Zenoh session that closes gives what it still holds for a peer a short grace (its queue is drained with
the keep-alive period, 2.5 s, per batch) and then closes the link; a slow app (a reading app beside two busy
loops) lost 227 of 314 frames that the broker had put in the second before its stop.  Zenoh says nothing of
what a link still holds, but the kernel does: `tx_queue` of each of this process's sockets in
/proc/net/tcp{,6} is what the peer has not acknowledged, which on a local link means its receive buffer is
full because the app is not reading.  So the broker, after its outboxes have drained and before it closes its
session, waits until those queues are empty (`wait`), or stuck (no byte taken for `stuck_s`: a stopped app,
which Zenoh cuts off after `wait_before_close` anyway), or `bound_s` has passed; and says what was left.
Linux only; elsewhere there is nothing to read and nothing is waited for (docs/runtime.md).
"""

from __future__ import annotations

import ipaddress
import os
import time
from collections.abc import Callable

TABLES = ("/proc/net/tcp", "/proc/net/tcp6")
QUIET_POLLS = 3
"""Polls in a row with nothing unsent before the wait ends: the session's own queue empties into the socket
between two polls, so one empty look is not yet the end."""


def own_sockets(fd_dir: str = "/proc/self/fd") -> set[str]:
    """Inodes of this process's sockets."""
    out = set()
    for fd in os.listdir(fd_dir):
        try:
            link = os.readlink(os.path.join(fd_dir, fd))
        except OSError:         # closed meanwhile
            continue
        if link.startswith("socket:["):
            out.add(link[8:-1])
    return out


def _addr(hexaddr: str) -> str:
    host, port = hexaddr.split(":")
    if len(host) == 8:          # IPv4, little-endian
        ip = ".".join(str(int(host[i:i + 2], 16)) for i in (6, 4, 2, 0))
    else:                       # IPv6, four little-endian words
        ip = f"[{ipaddress.IPv6Address(b''.join(bytes.fromhex(host[i:i + 8])[::-1] for i in range(0, 32, 8)))}]"
    return f"{ip}:{int(port, 16)}"


def unsent_in(table: str, inodes: set[str]) -> dict[str, int]:
    """Peer address -> bytes not yet acknowledged, for the established sockets (state 01) of `inodes` in the
    text of one /proc/net/tcp table."""
    out: dict[str, int] = {}
    for line in table.splitlines()[1:]:
        f = line.split()
        if len(f) > 9 and f[3] == "01" and f[9] in inodes:
            out[_addr(f[2])] = out.get(_addr(f[2]), 0) + int(f[4].split(":")[0], 16)
    return out


def unsent() -> dict[str, int]:
    """Peer address -> bytes not yet acknowledged, for this process's established TCP sockets."""
    try:
        inodes = own_sockets()
    except OSError:
        return {}
    out: dict[str, int] = {}
    for path in TABLES:
        try:
            with open(path) as fh:
                out.update(unsent_in(fh.read(), inodes))
        except OSError:
            continue
    return out


def wait(stuck_s: float = 2.0, bound_s: float = 10.0, poll_s: float = 0.05,
         look: Callable[[], dict[str, int]] = unsent, clock: Callable[[], float] = time.monotonic,
         sleep: Callable[[float], None] = time.sleep) -> dict[str, int]:
    """Wait until every socket has nothing unsent or is stuck (what it has unsent did not change for
    `stuck_s`), QUIET_POLLS looks in a row, or until `bound_s` has passed; return what is left unsent, by
    peer ({}: all went)."""
    t0 = clock()
    seen: dict[str, tuple[int, float]] = {}     # peer -> (bytes unsent, when that changed)
    quiet = 0
    while True:
        now = clock()
        left = {p: n for p, n in look().items() if n > 0}
        seen = {p: (n, seen[p][1] if p in seen and seen[p][0] == n else now) for p, n in left.items()}
        moving = any(now - since < stuck_s for _, since in seen.values())
        quiet = 0 if moving else quiet + 1
        if quiet >= QUIET_POLLS or now - t0 >= bound_s:
            return left
        sleep(poll_s)
