"""MAC state machines driven by uwsimnet_zenoh.mac.testing (no modem, no channel): the transitions of
docs/mac.md, one event at a time, with the timeouts computed from their formulas."""

from __future__ import annotations

import math

import pytest

from uwsimnet_zenoh.kernel.frame import BROADCAST, Frame
from uwsimnet_zenoh.mac import testing
from uwsimnet_zenoh.mac.aloha import MAC_HEADER
from uwsimnet_zenoh.mac.sfama import RTS_CTS_HEADER


def kinds(effects):
    return [(e[0], *(x for x in e[2:])) for e in effects]


# -- CS-ALOHA -------------------------------------------------------------------------------------------
def test_cs_aloha_idle_channel_sends_at_once_then_waits_for_the_ack():
    h = testing.Harness("cs-aloha")
    f = h.offer(dst=2, size=20)
    assert h.effects() == [("transmit", f)]
    h.tx_done()
    assert h.effects() == [("status", f, "transmitted")]     # an ACK is awaited: not final
    h.receive(h.ack_for(f))
    eff = h.effects()
    assert [e[0] for e in eff] == ["trace_rx", "status"] and eff[1][2] == "acked"


def test_cs_aloha_ack_timeout_is_its_formula():
    # 2 * max propagation + intrinsic tx delay + ACK air time + guard (docs/mac.md)
    h = testing.Harness("cs-aloha", {"maxDistance": "1500", "backoffMin": "0", "backoffMax": "0"},
                        tx_delay=0.05, bitrate=1000.0)
    timeout = 2 * 1500 / 1500 + 0.05 + MAC_HEADER * 8 / 1000 + 0.005
    assert h.mac.ack_timeout == pytest.approx(timeout)
    f = h.offer()
    h.tx_done()
    h.effects()
    h.advance_by(timeout - 1e-6)
    assert h.effects() == []                                  # not yet
    h.advance_by(2e-6)
    assert h.effects() == [("transmit", f)] and f.tries == 2  # retransmission, same frame, no backoff


def test_cs_aloha_busy_channel_backs_off_without_counting_a_failure():
    h = testing.Harness("cs-aloha", {"backoffMin": "1", "backoffMax": "1"})
    h.ctx.busy = True
    f = h.offer()
    assert h.effects() == [] and h.mac.state == "backoff"
    h.advance_by(1.0)                                         # still busy: another backoff
    assert h.effects() == [] and h.mac.fails == 0
    h.ctx.busy = False
    h.advance_by(1.0)
    assert h.effects() == [("transmit", f)] and h.now == pytest.approx(2.0)


def test_cs_aloha_gives_up_after_max_retries():
    h = testing.Harness("cs-aloha", {"maxRetries": "2", "backoffMin": "0", "backoffMax": "0"})
    f = h.offer()
    sent = 0
    for _ in range(10):
        if h.ctx.on_air is not None:
            h.tx_done()
            sent += 1
        h.advance_by(h.mac.ack_timeout + 1e-3)
    assert sent == 3                                           # the first attempt and 2 retries
    assert kinds(h.effects())[-2:] == [("drop", "retry"), ("status", "failed")]
    assert h.mac.cur is None and f.tries == 3


def test_cs_aloha_receiver_acks_duplicates_but_delivers_once():
    h = testing.Harness("cs-aloha", address=2)
    data = h.from_peer(src=1, seq=7)
    h.receive(data)
    eff = h.effects()
    assert [e[0] for e in eff] == ["transmit", "deliver"]
    ack = eff[0][1]
    assert ack.kind == "ctrl" and ack.dst == 1 and ack.info == {"type": "ACK", "seq": 7} and ack.size == MAC_HEADER
    h.tx_done()
    h.receive(data)                                            # the sender missed our ACK: it retransmits
    assert [e[0] for e in h.effects()] == ["transmit"]         # ACKed again, not delivered twice


def test_cs_aloha_broadcast_needs_no_ack():
    h = testing.Harness("cs-aloha")
    f = h.offer(dst=BROADCAST)
    h.tx_done()
    assert h.effects() == [("transmit", f), ("status", f, "sent")] and h.mac.cur is None


# -- S-FAMA ---------------------------------------------------------------------------------------------
def sfama(**params: str) -> testing.Harness:
    return testing.Harness("sfama", {"maxDistance": "1500", **params}, tx_delay=0.0, bitrate=1000.0, seed=3)


def test_sfama_slot_is_its_formula():
    h = sfama()
    slot = 0.005 + 0.0 + RTS_CTS_HEADER * 8 / 1000 + 1500 / 1500
    assert h.mac.slot == pytest.approx(slot)


def test_sfama_rts_at_a_slot_start_then_data_two_slots_later_after_the_cts():
    h = sfama()
    f = h.offer(dst=2, size=20)
    rts = h.until_transmit()
    assert h.effects() == [("transmit", rts)] and rts.info["type"] == "RTS" and rts.dst == 2
    assert h.now < 4 * h.mac.slot                              # backoff U{0..3} slots
    n = h.now / h.mac.slot
    assert n == pytest.approx(round(n))                       # at a slot boundary
    d = math.ceil((20 * 8 / 1000 + 1.0) / h.mac.slot)
    assert rts.info["slots"] == d                             # data slots announced
    h.tx_done()
    cts = Frame(2, 1, f.seq, RTS_CTS_HEADER, 0, kind="ctrl", info={"type": "CTS", "slots": d})
    h.advance((round(n) + 1.5) * h.mac.slot)                  # the CTS arrives during slot n+1
    h.receive(cts)
    assert [e[0] for e in h.effects()] == ["trace_rx"]
    assert h.until_transmit() is f                             # DATA at the start of slot n+2
    assert h.now == pytest.approx((round(n) + 2) * h.mac.slot)


def test_sfama_no_cts_is_a_failed_attempt_and_a_new_backoff():
    h = sfama(maxRetries="0")
    f = h.offer()
    h.until_transmit()
    h.effects()
    h.tx_done()                                               # our RTS left; nobody answers
    h.advance(h.now + 2 * h.mac.slot + 1e-6)                  # the end of slot n+1
    assert kinds(h.effects()) == [("drop", "retry"), ("status", "failed")]
    assert f.tries == 0                                       # the DATA never went


def test_sfama_overheard_rts_defers_our_rts():
    h = sfama()
    h.offer(dst=2)
    other = Frame(3, 4, 0, RTS_CTS_HEADER, 0, kind="ctrl", info={"type": "RTS", "slots": 2})
    h.overhear(other)
    assert h.mac.nav == pytest.approx((h.mac.slot_index(0.0) + 3 + 2) * h.mac.slot)
    h.advance(h.mac.nav - 1e-6)
    assert h.effects() == []                                  # silent until the exchange we heard ends


def test_harness_catches_a_mac_that_transmits_while_busy():
    from uwsimnet_zenoh.mac import Mac

    class Eager(Mac):
        def on_queue(self) -> None:
            self.ctx.transmit(self.ctx.fifo_pop())

    h = testing.Harness(Eager)
    h.offer()
    with pytest.raises(AssertionError, match="transmit while the transmitter is busy"):
        h.offer()


def test_the_example_in_docs_mac_md_runs():
    from pathlib import Path

    text = (Path(__file__).resolve().parent.parent / "docs" / "mac.md").read_text()
    block = text.split("### Testing your MAC", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(block, "docs/mac.md", "exec"), {})  # noqa: S102 - our own documentation, not user input


# -- DcMac (dccomms_examples src/DcMac.cpp at 3cfb74d; docs/mac.md "DcMac") ---------------------------
def dcmac(address: int, **params: str) -> testing.Harness:
    return testing.Harness("dcmac", {"maxDistance": "150", "maxNodes": "2", **params}, address=address,
                           tx_delay=0.001, bitrate=1000.0)


def ctrl(src: int, to: int, **info) -> Frame:
    return Frame(src, to, -1, 7, 0, kind="ctrl", info=info)


def test_dcmac_slot_and_master_cycle_are_the_originals_formulas():
    h = dcmac(0)
    # UpdateSlotDurFromEstimation (:448-461): 7-byte RTS at 1000 bps + 1 ms + 150 m / 1500 m/s + 45 ms, whole ms
    assert h.mac.slot == pytest.approx(0.202)
    sync = h.until_transmit()
    assert (h.now, sync.size, sync.dst, sync.info["type"]) == (0.0, 6, BROADCAST, "SYNC")
    h.tx_done()
    # nobody asks: minEnd2End + 2 RTS slots, no data, 10 ms, next SYNC.  minEnd2End = (6*8 / 1000) [integer
    # division: 0] * 1000 + 1 ms (DcMac.cpp:740-743), not the SYNC's 48 ms of airtime
    nxt = h.until_transmit()
    assert nxt.info["type"] == "SYNC" and h.now == pytest.approx(0.001 + 2 * 0.202 + 0.010)


def test_dcmac_slave_rts_in_its_slot_data_on_cts_acked_by_the_next_sync():
    h = dcmac(2)
    f = h.offer(dst=0, size=21)
    h.receive(ctrl(0, BROADCAST, type="SYNC", acks=[]))
    t0 = h.now
    rts = h.until_transmit()
    assert rts.info["type"] == "RTS" and h.now - t0 == pytest.approx(0.202)      # (addr-1) * slot (:469)
    assert rts.info["size"] == 22 and rts.size == 7          # the size field holds half, rounded up (:243)
    h.tx_done()
    h.receive(ctrl(0, 2, type="CTS", size=22))
    assert h.effects()[-1] == ("transmit", f)
    h.tx_done()
    h.receive(ctrl(0, BROADCAST, type="SYNC", acks=[1]))     # not our bit: lost, asked for again
    assert ("status", f, "acked") not in h.effects()
    again = h.until_transmit()
    assert again.info["type"] == "RTS" and again.info["size"] == 22
    h.tx_done()
    h.receive(ctrl(0, 2, type="CTS", size=22))
    h.tx_done()
    h.receive(ctrl(0, BROADCAST, type="SYNC", acks=[2]))
    assert ("status", f, "acked") in h.effects()


def test_dcmac_master_grants_the_fewest_bytes_first_and_acks_in_the_sync():
    h = dcmac(0)
    h.until_transmit()
    h.tx_done()
    h.receive(ctrl(1, 0, type="RTS", size=40, dst=0, acks=[]))
    h.receive(ctrl(2, 0, type="RTS", size=10, dst=0, acks=[]))
    cts = h.until_transmit()
    assert cts.info["type"] == "CTS" and cts.dst == 1         # equal (zero) bytes granted: the lower slave
    h.tx_done()
    h.receive(h.from_peer(src=1, dst=0, size=40))             # its data ends the wait at once
    cts2 = h.until_transmit()
    assert cts2.dst == 2
    h.tx_done()
    h.advance_by(0.202 + 0.011 + 0.001)                       # slave 2 sends nothing: slot + its tx time, ceil ms
    sync = h.until_transmit()
    assert sync.info["type"] == "SYNC" and sync.info["acks"] == [1]


def test_dcmac_refuses_broadcast_frames():
    h = dcmac(1)
    f = h.offer(dst=BROADCAST, size=10)
    h.receive(ctrl(0, BROADCAST, type="SYNC", acks=[]))
    h.advance_by(1.0)
    assert ("drop", f, "broadcast") in [e[:3] for e in h.effects()]


@pytest.mark.parametrize("aquasim, wait_slots", [("0", None), ("1", 1)])
def test_sfama_ack_wait_ends_one_slot_after_the_coming_slot_start_with_aquasims_rule(aquasim, wait_slots):
    """aqua-sim-mac-sfama.cc@0653634 StatusProcess :777-836: after the DATA's last bit, WAIT_RECV_ACK for
    slotLen * 1 + GetTime2ComingSlot(now); ours (off): to the end of slot n+2+D."""
    h = sfama(ackWaitAquasim=aquasim)
    f = h.offer(dst=2, size=20)
    h.until_transmit()
    n = round(h.now / h.mac.slot)
    d = h.mac.data_slots(f)
    h.tx_done()
    h.advance((n + 1.5) * h.mac.slot)
    h.receive(Frame(2, 1, f.seq, RTS_CTS_HEADER, 0, kind="ctrl", info={"type": "CTS", "slots": d}))
    h.until_transmit()
    h.advance_by(20 * 8 / 1000)                               # the DATA's airtime (tx_delay 0)
    h.tx_done()
    last_bit = h.now
    h.effects()
    coming = math.ceil(last_bit / h.mac.slot) * h.mac.slot
    end = coming + h.mac.slot if wait_slots else (n + 3 + d) * h.mac.slot
    h.advance(end - 1e-6)
    assert h.mac.state == "wait_ack"
    h.advance(end + 1e-6)
    assert h.mac.state != "wait_ack"                          # failed attempt: the ACK did not come

