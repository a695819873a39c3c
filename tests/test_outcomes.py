"""`Outcomes` (drivers/zenoh_backend.py): the addressee's outcome of a unicast frame from the trace records,
whichever comes first of the record and the status that tells the frame's seq.  They are different Zenoh
keys with no order between them: on a loaded machine a 1-byte burst's rx record came first, was ignored,
and the EvoLogics emulator reported FAILED for a frame the trace says was received."""

from __future__ import annotations

from uwsimnet_zenoh.drivers.zenoh_backend import Outcomes


def _rec(ev: str, dev: str, seq: int, **kw: object) -> dict:
    return {"ev": ev, "dev": dev, "src": 1, "seq": seq, "kind": "data", "t": 2.5, **kw}


def test_an_outcome_seen_before_the_watch_is_reported_at_the_watch() -> None:
    o, got = Outcomes(), []
    o.on_trace(_rec("rx", "b-m", 10, dist=150.0))
    o.watch(1, 10, "a-m", lambda *a: got.append(a))
    assert got == [("delivered", None, 2.5, 150.0)]
    o.on_trace(_rec("rx", "c-m", 10))                   # once only
    assert len(got) == 1


def test_the_senders_own_records_are_not_its_outcome_either_way() -> None:
    o, got = Outcomes(), []
    o.on_trace(_rec("drop", "a-m", 11, reason="fifo"))  # at the sender: its own status, not the addressee's
    o.watch(1, 11, "a-m", lambda *a: got.append(a))
    assert got == []
    o.on_trace(_rec("drop", "b-m", 11, reason="col"))
    assert got == [("lost", "col", 2.5, None)]


def test_after_the_watch_as_before_and_unwatched_records_are_bounded() -> None:
    o, got = Outcomes(limit=3), []
    o.watch(1, 12, "a-m", lambda *a: got.append(a))
    o.on_trace(_rec("rx", "b-m", 12))
    assert got == [("delivered", None, 2.5, None)]
    for seq in range(100, 110):
        o.on_trace(_rec("rx", "b-m", seq))
    o.watch(1, 100, "a-m", lambda *a: got.append(a))    # forgotten: only the last 3 are kept
    o.watch(1, 109, "a-m", lambda *a: got.append(a))
    assert len(got) == 2
