"""Aqua-Sim NG's S-FAMA rules as parameters of our S-FAMA (issue #16; docs/mac.md, "Aqua-Sim's rules").

Each rule is checked against the same events with the rule off (our default) and on, on the MAC harness:
what the MAC transmits, delivers and reports.  The rules are read from rmartin5/aqua-sim-ng,
model/aqua-sim-mac-sfama.cc at 0653634 (ProcessRTS, ProcessCTS, ProcessDATA, WaitReplyTimerProcess)."""

from __future__ import annotations

import pytest

from uwsimnet_zenoh.kernel.frame import BROADCAST, Frame
from uwsimnet_zenoh.mac import testing
from uwsimnet_zenoh.mac.sfama import RETRY_BACKOFF, RTS_CTS_HEADER

AQUASIM = {"broadcast": "aquasim", "answerRtsInBackoff": "0", "overhearEndsRound": "1", "carrierSense": "0"}


def sfama(**params: str) -> testing.Harness:
    return testing.Harness("sfama", {"maxDistance": "1500", **params}, tx_delay=0.0, bitrate=1000.0, seed=3)


def ctrl(src: int, dst: int, kind: str, seq: int = 0, slots: int = 2) -> Frame:
    return Frame(src, dst, seq, RTS_CTS_HEADER, 0, kind="ctrl", info={"type": kind, "slots": slots})


def sent(effects, kind: str | None = None) -> list[Frame]:
    """The frames transmitted among `effects` (control frames of `kind` only, if given)."""
    out = [e[1] for e in effects if e[0] == "transmit"]
    return out if kind is None else [f for f in out if (f.info or {}).get("type") == kind]


def statuses(effects) -> list[str]:
    return [e[2] for e in effects if e[0] == "status"]


def test_defaults_are_ours_and_bad_values_are_named():
    m = sfama().mac
    assert (m.broadcast_mode, m.answer_rts_in_backoff, m.overhear_ends_round, m.carrier_sense) == \
        ("rts", True, False, True)
    m = sfama(**AQUASIM).mac
    assert (m.broadcast_mode, m.answer_rts_in_backoff, m.overhear_ends_round, m.carrier_sense) == \
        ("aquasim", False, True, False)
    with pytest.raises(ValueError, match="broadcast: expected one of rts, aquasim, drop"):
        sfama(broadcast="flood")
    with pytest.raises(ValueError, match="overhearEndsRound: expected 0 or 1"):
        sfama(overhearEndsRound="2")
    with pytest.raises(ValueError, match="carrierSense: expected a number"):
        sfama(carrierSense="yes")


# -- broadcast ------------------------------------------------------------------------------------
def test_broadcast_default_rts_then_data_two_slots_later():
    h = sfama()
    f = h.offer(dst=BROADCAST)
    rts = h.until_transmit()
    n = round(h.now / h.mac.slot)
    h.tx_done()
    assert rts.info["type"] == "RTS" and rts.dst == BROADCAST
    assert h.until_transmit() is f and h.now == pytest.approx((n + 2) * h.mac.slot)


def test_broadcast_aquasim_is_an_rts_nobody_answers_so_the_data_never_goes():
    # Aqua-Sim: ProcessRTS answers only an RTS whose destination is the node's own address, so the RTS to
    # 255 gets no CTS; the sender times out and retries (maxRetries here; Aqua-Sim: for ever)
    h = sfama(broadcast="aquasim", maxRetries="1")
    f = h.offer(dst=BROADCAST)
    rtss = []
    for _ in range(2):
        rtss.append(h.until_transmit())
        h.tx_done()
    h.advance(h.now + 2 * h.mac.slot + 1e-6)
    eff = h.effects()
    assert [r.info["type"] for r in rtss] == ["RTS", "RTS"] and all(r.dst == BROADCAST for r in rtss)
    assert f.tries == 0                                           # the DATA never went on air
    assert [e[0] for e in eff][-2:] == ["drop", "status"] and eff[-2][2] == "retry" and eff[-1][2] == "failed"


def test_broadcast_drop_refuses_it_and_goes_on_with_the_next_frame():
    h = sfama(broadcast="drop")
    b = h.offer(dst=BROADCAST)
    u = h.offer(dst=2)
    assert h.effects()[:1] == [("drop", b, "broadcast")]
    rts = h.until_transmit()
    assert rts.dst == 2 and rts.seq == u.seq


# -- an RTS while backing off after a failed attempt ------------------------------------------------
def _after_a_failed_attempt(h: testing.Harness) -> None:
    h.offer(dst=2)
    h.until_transmit()
    h.tx_done()                                                   # our RTS left; no CTS comes
    h.advance(h.now + 2 * h.mac.slot + 1e-6)                      # end of slot n+1: failed attempt
    h.effects()


def test_rts_answered_in_the_backoff_after_a_failure_by_default():
    h = sfama(maxBackoffSlots="50")
    _after_a_failed_attempt(h)
    assert h.mac.state == "backoff"
    h.receive(ctrl(3, 1, "RTS"))
    h.advance(h.now + h.mac.slot)
    assert [f.dst for f in sent(h.effects(), "CTS")] == [3]       # CTS at the next slot start


def test_rts_not_answered_in_the_backoff_after_a_failure_with_answerRtsInBackoff_0():
    h = sfama(maxBackoffSlots="50", answerRtsInBackoff="0")
    _after_a_failed_attempt(h)
    assert h.mac.state == RETRY_BACKOFF                           # Aqua-Sim's BACKOFF: deaf to RTSs
    h.receive(ctrl(3, 1, "RTS"))
    h.advance(h.now + h.mac.slot)
    assert sent(h.effects(), "CTS") == []
    # then the usual backoff before the RTS (Aqua-Sim's WAIT_SEND_RTS), in which an RTS is answered
    while h.mac.state == RETRY_BACKOFF:
        h.advance(h.now + h.mac.slot)
    assert h.mac.state == "backoff"
    h.receive(ctrl(4, 1, "RTS"))
    h.advance(h.now + h.mac.slot)
    assert [f.dst for f in sent(h.effects(), "CTS")] == [4]


def test_two_backoff_draws_after_a_failure_with_answerRtsInBackoff_0():
    # Aqua-Sim: WaitReplyTimerProcess backs off k slots, then ScheduleRTS draws k' more: the retried RTS
    # comes k + k' slots after the end of the failed attempt, each U{0..3}; ours: one draw
    gaps = {}
    for rule in ("1", "0"):
        g = []
        for seed in range(1, 60):
            h = testing.Harness("sfama", {"maxDistance": "1500", "maxRetries": "1", "answerRtsInBackoff": rule},
                                bitrate=1000.0, seed=seed)
            h.offer(dst=2)
            h.until_transmit()
            h.tx_done()
            fail = (round(h.now / h.mac.slot) + 2) * h.mac.slot
            h.until_transmit()
            g.append(round((h.now - fail) / h.mac.slot))
        gaps[rule] = g
    assert max(gaps["1"]) <= 4 and max(gaps["0"]) <= 7              # ours: first slot after + U{0..3}
    assert max(gaps["0"]) > 4                                       # two draws reach beyond one window


# -- an overheard RTS/CTS ends the round in any state ------------------------------------------------
def _data_sent_waiting_for_ack(h: testing.Harness) -> Frame:
    f = h.offer(dst=2)
    rts = h.until_transmit()
    n = round(h.now / h.mac.slot)
    h.tx_done()
    h.advance((n + 1.5) * h.mac.slot)
    h.receive(ctrl(2, 1, "CTS", seq=f.seq, slots=rts.info["slots"]))
    assert h.until_transmit() is f
    h.tx_done()
    h.effects()
    return f


def test_overheard_rts_while_waiting_for_the_ack_default_keeps_the_round():
    h = sfama()
    f = _data_sent_waiting_for_ack(h)
    h.overhear(ctrl(3, 4, "RTS"))
    h.receive(h.ack_for(f))
    assert statuses(h.effects()) == ["acked"]


def test_overheard_rts_while_waiting_for_the_ack_ends_the_round_with_overhearEndsRound():
    h = sfama(overhearEndsRound="1")
    f = _data_sent_waiting_for_ack(h)
    h.overhear(ctrl(3, 4, "RTS"))
    assert h.mac.state == "backoff" and h.mac.fails == 0          # not a failed attempt
    h.receive(h.ack_for(f))
    assert statuses(h.effects()) == []                            # Aqua-Sim ignores an ACK out of its round
    rts = h.until_transmit()                                      # the same frame again, after the deferral
    assert rts.info["type"] == "RTS" and rts.seq == f.seq and h.now >= h.mac.nav - 1e-9


def _rts_for_us(h: testing.Harness) -> tuple[Frame, int]:
    h.advance(0.5 * h.mac.slot)                                   # within slot 0
    h.receive(ctrl(2, 1, "RTS", seq=7, slots=2))
    return Frame(2, 1, 7, 20, 20), 0


def test_responder_overhearing_a_cts_default_still_answers_and_acks():
    h = sfama()
    data, n = _rts_for_us(h)
    h.overhear(ctrl(3, 4, "CTS"))                                 # someone else's CTS, before ours goes
    h.advance((n + 1) * h.mac.slot + 1e-9)
    assert [f.dst for f in sent(h.effects(), "CTS")] == [2]
    h.tx_done()
    h.advance((n + 2.5) * h.mac.slot)
    h.receive(data)
    h.advance((n + 3) * h.mac.slot + 1e-9)
    eff = h.effects()
    assert ("deliver", data) in eff and [f.dst for f in sent(eff, "ACK")] == [2]


def test_responder_overhearing_a_cts_drops_its_round_with_overhearEndsRound():
    h = sfama(overhearEndsRound="1")
    data, n = _rts_for_us(h)
    h.overhear(ctrl(3, 4, "CTS"))
    h.advance((n + 1) * h.mac.slot + 1e-9)
    assert sent(h.effects(), "CTS") == []                         # the CTS not yet sent is not sent
    h.advance((n + 2.5) * h.mac.slot)
    h.receive(data)                                               # the DATA of the abandoned round
    h.advance((n + 3) * h.mac.slot + 1e-9)
    eff = h.effects()
    assert ("deliver", data) not in eff and sent(eff) == []       # neither delivered nor acknowledged


def test_responder_overhearing_an_rts_before_its_ack_sends_no_ack_with_overhearEndsRound():
    h = sfama(overhearEndsRound="1")
    data, n = _rts_for_us(h)
    h.advance((n + 1) * h.mac.slot + 1e-9)
    h.tx_done()                                                   # our CTS left
    h.advance((n + 2.5) * h.mac.slot)
    h.receive(data)                                               # in its round: delivered at once
    h.overhear(ctrl(3, 4, "RTS"))                                 # before the ACK slot
    h.advance((n + 3) * h.mac.slot + 1e-9)
    eff = h.effects()
    assert ("deliver", data) in eff and sent(eff, "ACK") == []


def test_a_cts_for_us_we_do_not_wait_for_defers_us_with_overhearEndsRound():
    for rule, deferred in (("0", False), ("1", True)):
        h = sfama(overhearEndsRound=rule)
        h.receive(ctrl(2, 1, "CTS", seq=9, slots=2))              # a stray CTS (its RTS was not ours)
        assert (h.mac.nav > 0) is deferred


# -- carrier sense ----------------------------------------------------------------------------------
def test_carrier_sense_off_sends_the_rts_on_a_busy_channel():
    h = sfama()
    h.ctx.busy = True
    h.offer(dst=2)
    with pytest.raises(AssertionError, match="no transmission"):
        h.until_transmit(limit=20 * h.mac.slot)                   # ours: busy channel, no RTS
    h = sfama(carrierSense="0")
    h.ctx.busy = True
    h.offer(dst=2)
    assert h.until_transmit(limit=4 * h.mac.slot).info["type"] == "RTS"
