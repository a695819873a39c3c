"""bus/flush.py: what this process's TCP peers have not taken yet, and the broker's bounded wait for it at its
stop (docs/runtime.md).  The table parser on /proc text, the wait's rules on a scripted look, and the kernel's
count over a real socket pair."""

from __future__ import annotations

import socket
import sys
import time

import pytest

from uwsimnet_zenoh.bus import flush

TABLE = """\
  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode
   0: 00000000:1D27 00000000:0000 0A 00000000:00000000 00:00000000 00000000     0        0 111 1 0 100 0 0 10 0
   1: 0100007F:1D27 0100007F:B3A2 01 0003E800:00000000 01:00000014 00000000     0        0 222 1 0 20 4 30 10 -1
   2: 0100007F:1D27 0100007F:B3A4 01 00000010:00000000 00:00000000 00000000     0        0 333 1 0 20 4 30 10 -1
   3: 0100007F:1D27 0100007F:B3A6 06 00000400:00000000 03:00000582 00000000     0        0 222 3 0
"""
TABLE6 = """\
  sl  local_address                         remote_address                        st tx_queue rx_queue tr tm->when \
retrnsmt   uid  timeout inode
   0: 00000000000000000000000001000000:1D27 00000000000000000000000001000000:C350 01 00000800:00000000 00:00000000 \
00000000     0        0 444 1 0 20 4 30 10 -1
"""


def test_the_table_gives_each_established_peer_of_our_sockets_its_unacknowledged_bytes():
    # 222: ours, established, 256000 bytes unsent; 333: not ours; the listener and a TIME_WAIT line are not links
    assert flush.unsent_in(TABLE, {"111", "222"}) == {"127.0.0.1:45986": 256000}
    assert flush.unsent_in(TABLE, {"333"}) == {"127.0.0.1:45988": 16}
    assert flush.unsent_in(TABLE6, {"444"}) == {"[::1]:50000": 2048}
    assert flush.unsent_in(TABLE, set()) == {}


class Script:
    """A scripted look (one dict per poll, the last repeated) on a clock that the wait's sleeps advance."""

    def __init__(self, looks: list[dict[str, int]]) -> None:
        self.looks, self.t, self.n = looks, 0.0, 0

    def look(self) -> dict[str, int]:
        self.n += 1
        return self.looks[min(self.n, len(self.looks)) - 1]

    def sleep(self, s: float) -> None:
        self.t += s

    def wait(self, **kw) -> dict[str, int]:
        # polls of 0.125 s: exact in binary, no rounding at the bounds
        return flush.wait(look=self.look, clock=lambda: self.t, sleep=self.sleep, poll_s=0.125, **kw)


def test_the_wait_ends_when_every_peer_has_taken_everything():
    s = Script([{"a": 300}, {"a": 200, "b": 5}, {"a": 100}, {"a": 0}, {}])
    assert s.wait() == {}
    assert s.n == 4 + flush.QUIET_POLLS - 1        # three empty looks in a row, not one


def test_a_peer_that_takes_nothing_is_stuck_after_stuck_s_and_the_wait_ends_without_it():
    s = Script([{"a": 300, "stopped": 999}, {"a": 200, "stopped": 999}, {"stopped": 999}])
    assert s.wait(stuck_s=2.0) == {"stopped": 999}
    assert s.t == 2.0 + 0.125 * (flush.QUIET_POLLS - 1)


def test_a_slow_peer_is_waited_for_up_to_the_bound():
    s = Script([{"slow": 10_000_000 - 1000 * i} for i in range(1000)])     # takes 1000 bytes a poll
    assert s.wait(stuck_s=2.0, bound_s=10.0) == {"slow": 10_000_000 - 1000 * 80}     # the look at 10 s
    assert s.t == 10.0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/net/tcp is Linux's")
def test_the_kernel_counts_what_a_peer_that_does_not_read_has_not_taken():
    srv = socket.create_server(("127.0.0.1", 0))
    cli = socket.create_connection(srv.getsockname())
    conn, _ = srv.accept()
    try:
        conn.setblocking(False)
        sent = 0
        try:
            while True:                             # until the reader's buffer and ours are full
                sent += conn.send(bytes(65536))
        except BlockingIOError:
            pass
        peer = f"127.0.0.1:{cli.getsockname()[1]}"
        assert 0 < flush.unsent()[peer] <= sent     # what the reader's kernel has not acknowledged
        assert flush.wait(stuck_s=0.3, poll_s=0.05)[peer] == flush.unsent()[peer]    # nobody reads: stuck
        got = 0
        cli.settimeout(10)
        while got < sent:                           # the reader reads it all: nothing left
            got += len(cli.recv(1 << 20))
        deadline = time.monotonic() + 10
        while flush.unsent().get(peer) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert flush.unsent().get(peer, 0) == 0
        assert peer not in flush.wait(stuck_s=0.3, poll_s=0.05)     # (other tests' sockets may be listed)
    finally:
        for s in (conn, cli, srv):
            s.close()
