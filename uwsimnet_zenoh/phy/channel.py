"""The shared medium: who hears a transmission, when, and whether it survives.

Design for speed (issue #2): a transmission is handled in ONE call at its first bit.  Distances,
propagation delays and range checks for every listener are computed together (as Python lists on a small
channel, with numpy on a large one) and kept in a `Transmission` record (arrival and end time per
listener).  Only receivers that must learn the outcome
(the addressee, every listener for broadcast, and MACs that overhear) get an event, at the end of their
reception.  Collisions are then decided by looking at the few transmissions still in the air log: two
receptions at the same listener whose intervals overlap are both lost; a half-duplex listener's own
transmission is an interval in its own column, so receiving while transmitting is a collision too.
Carrier sense is a query on the same log.  ns-3 spends 2-3 events per receiver per frame instead.
A channel in SINR mode (acoustic, issue #5) keeps each transmission's received power per listener and
replaces the binary rule by capture on the minimum SINR (`_reception_end_sinr`, phy.interference).
What a receiver gets of the signal (loss probability, and a propagation delay if the model has its own) is
the transmitter's channel model's answer (phy.models): one `answer` call per transmission for all the
receivers that need an outcome; the channel does not know which model it is.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Final, cast

from ..kernel.frame import BROADCAST, Frame
from ..kernel.rx import with_details
from .interference import classify, min_sinr_db
from .models import Query

if TYPE_CHECKING:
    import numpy as np

    from ..kernel.scheduler import Scheduler
    from ..mobility.trajectory import PoseTable
    from ..trace.tracer import Tracer
    from .modem import Modem, SinrLossModel

INF: Final = float("inf")
TOUCH: Final = 1e-9
"""Receptions that overlap by less than a nanosecond touch: back-to-back frames from one modem end and
begin at the same instant, but float rounding of (t0 + dur) + delay vs (t0 + delay) + dur can make them
overlap by ~1e-16 s, which must not count as a collision."""


LIST_SLOTS: Final = 512
"""Up to this many listener slots the geometry is Python lists, computed in a loop, and numpy is not even
imported (a third of a small run's start-up): the per-frame path reads a few slots one by one (the
addressee, the log's transmissions at one slot), and a list item is a Python float read in a few ns where
a numpy scalar costs ~100 ns to make and more to add or compare.  Above it, numpy arrays.  Both compute the
same doubles in the same order (`_geometry_lists`, `_geometry_arrays`), so the choice changes no outcome."""

Geometry = tuple[Any, Any, Any, float]
"""What `Channel._geometry` gives: distance, delay, reach per slot (lists on a small channel, else
arrays) and the longest finite delay."""

GEO_CACHE_SLOTS: Final = 8_000_000
"""At most this many (sender, listener) pairs of cached geometry per channel (17 bytes each): every sender
of a small network, ~800 of 10 000 on one channel (the others' geometry is computed when they send)."""


class Transmission:
    """One frame in the air: its arrival/end time at every listener slot (inf = never arrives).

    Arrival at slot j is `t0 + dl[j]`, the end `t0 + dl[j] + dur` (the same doubles as the arrays `arr`
    and `end`, which are built only when asked for: the binary rule and carrier sense read the few slots
    they need from the shared delays `dl` of the sender's geometry, a list when the channel is small
    (LIST_SLOTS), else an array; `dd` the distances alike).  `own` is the sender's slot on this channel if
    it listens there (half duplex: its own signal occupies its receiver), else -1."""

    __slots__ = ("frame", "sender", "t0", "dur", "dl", "own", "_arr", "_end", "max_end", "dd", "pow", "acq", "info")

    def __init__(self, frame: Frame, sender: Modem, t0: float, dur: float, dl: list[float] | np.ndarray,
                 dd: list[float] | np.ndarray, max_end: float, own: int = -1) -> None:
        self.frame = frame
        self.sender = sender
        self.t0 = t0
        self.dur = dur
        self.dl = dl
        self.own = own
        self._arr: np.ndarray | None = None
        self._end: np.ndarray | None = None
        self.dd = dd
        self.max_end = max_end
        self.pow: np.ndarray | None = None    # received power per listener slot, linear (SINR mode only)
        self.acq: dict[int, bool] | None = None   # slot -> acquired (SINR mode, capture "first" only)
        self.info: dict[int, tuple[Any, Any]] | None = None
        """slot -> (Doppler factor, received level dB) of the model's answer, when it gave either."""

    def distance(self, j: int) -> float:
        """The distance to slot j, m (from the list when there is one: no numpy scalar made)."""
        d = self.dd
        if isinstance(d, list):
            dlist: list[float] = d
            return dlist[j]
        return float(d[j])

    def rx(self, j: int) -> Any:
        """What slot j's modem gets with the frame (kernel.rx): the distance, with the model's details if any."""
        info = self.info
        if info is None:
            return self.distance(j)
        hit = info.get(j)
        if hit is None:
            return self.distance(j)
        return with_details(self.distance(j), hit[0], hit[1])

    def keep_details(self, targets: Any, doppler: Any, level: Any) -> None:
        """Keep the model's Doppler factors and received levels (either may be None) of `targets`."""
        info = self.info
        if info is None:
            info = self.info = {}
        for n, j in enumerate(targets):
            info[j] = (None if doppler is None else float(doppler[n]), None if level is None else float(level[n]))

    @property
    def powers(self) -> np.ndarray:
        """SINR mode: the received power per slot (set before the transmission enters the air log)."""
        assert self.pow is not None, "a transmission without powers in SINR mode"
        return self.pow

    @property
    def arr(self) -> np.ndarray:
        if self._arr is None:
            import numpy as np

            self._arr = np.asarray(self.dl, dtype=np.float64) + self.t0
        return self._arr

    @property
    def end(self) -> np.ndarray:
        if self._end is None:
            self._end = self.arr + self.dur
        return self._end


class Channel:
    """A `CustomCommsChannel`: delay = min_prop_s + prop_s_per_m * distance at transmission start."""

    def __init__(self, cid: int, prop_s_per_m: float, min_prop_s: float, sched: Scheduler,
                 poses: PoseTable, tracer: Tracer, *, sinr: bool = False,
                 sinr_threshold_db: float | None = None, lock_first_db: float | None = None) -> None:
        self.id = cid
        # SINR mode (an AcousticCommsChannel with <interference>sinr</interference>): overlapping frames
        # add to the noise and a frame survives on its minimum SINR (capture) instead of the binary rule;
        # every sender's `error` must then give received_power(d), noise_power and per_from_sinr(sinr, L).
        self.sinr = sinr
        self.sinr_threshold_db = sinr_threshold_db
        # capture "first" (ns-3 UanPhyGen): a receiver locks onto the first frame whose SINR at its arrival
        # exceeds lock_first_db and cannot receive another until that one ends; None: any frame may capture
        self.lock_first_db = lock_first_db
        self._pow_cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.captures = 0                           # SINR mode: frames received although others overlapped
        self.prop_s_per_m = prop_s_per_m
        self.min_prop_s = min_prop_s
        self.sched = sched
        self.poses = poses
        self.tracer = tracer
        self.listeners: list[Modem | None] = []   # slot -> modem (None once detached; slots never move)
        self._veh: list[int] = []                   # slot -> vehicle index in the pose table
        self._alive: list[bool] = []
        self._by_addr: dict[int, int] = {}
        self._overhearing: list[int] = []
        self.log: deque[Transmission] = deque()
        self._members = 0                           # bumped on attach/detach (invalidates geometry)
        self._geo_cache: dict[str, tuple[int, int, Geometry]] = {}
        self._slots: tuple | None = None            # (pose version, members, alive & known, slot positions)
        self._members_np: tuple | None = None       # (members, slot -> vehicle, alive) as numpy arrays
        self._longest = 0.0
        self.transmissions = 0
        self._end_at: Callable[[Transmission, int, bool, bool], None] = self._reception_end    # bound once
        self._end_sinr_at: Callable[[Transmission, int, float, float, bool], None] = self._reception_end_sinr

    # -- membership ---------------------------------------------------------------------------
    def attach(self, modem: Modem) -> int:
        slot = len(self.listeners)
        self.listeners.append(modem)
        self._veh.append(modem.vehicle_index)
        self._alive.append(True)
        self._by_addr[modem.address] = slot
        if modem.overhears:                 # slots only grow: the list stays in slot order
            self._overhearing.append(slot)
        self._members += 1
        return slot

    def detach(self, modem: Modem) -> None:
        slot = modem.rx_slot
        self.listeners[slot] = None
        self._alive[slot] = False
        if self._by_addr.get(modem.address) == slot:
            del self._by_addr[modem.address]
        self._refresh_overhearing()
        self._members += 1

    def _refresh_overhearing(self) -> None:
        self._overhearing = [i for i, m in enumerate(self.listeners) if m is not None and m.overhears]

    def has_address(self, address: int) -> bool:
        return address in self._by_addr

    def max_prop_delay(self, max_distance: float) -> float:
        return self.min_prop_s + self.prop_s_per_m * max_distance

    # -- the per-frame path --------------------------------------------------------------------
    def _geometry(self, sender: Modem, now: float) -> Geometry:
        """Distance, propagation delay (inf where out of range) and reach from `sender` to every slot, and
        the longest finite delay: Python lists on a small channel (LIST_SLOTS), else numpy arrays.

        With no vehicle moving these only change with membership, so they are cached per sender."""
        poses = self.poses
        key = sender.id
        if not poses.moving:
            hit = self._geo_cache.get(key)
            if hit is not None and hit[0] == poses.version and hit[1] == self._members:
                return hit[2]
        n = len(self._veh)
        geo = self._geometry_lists(sender, now) if n <= LIST_SLOTS else self._geometry_arrays(sender, now)
        if not poses.moving:
            cache = self._geo_cache
            if (len(cache) + 1) * n > GEO_CACHE_SLOTS:    # bounded: forget the oldest senders
                for old in list(cache)[:max(1, len(cache) // 4)]:
                    del cache[old]
                    self._pow_cache.pop(old, None)
            cache[key] = (poses.version, self._members, geo)
        return geo

    def _geometry_lists(self, sender: Modem, now: float) -> Geometry:
        """A small channel's geometry, one slot at a time.  The distance is sqrt((dx² + dz²) + dy²): the
        order in which numpy's einsum summed the squares (its SIMD lanes), kept by both paths so that
        traces stay what they were; the delay min_prop + per_m * d, as numpy computes it."""
        pts = self.poses.points(now)
        known = self.poses.known
        si = sender.vehicle_index
        sx, sy, sz = pts[si]
        src_known = known[si]
        lo = sender.min_distance
        hi = sender.max_distance
        base = self.min_prop_s
        per_m = self.prop_s_per_m
        own = sender.rx_slot if sender.rx_channel is self else -1
        veh = self._veh
        alive = self._alive
        dist: list[float] = []
        delay: list[float] = []
        ok: list[bool] = []
        longest = 0.0
        for k in range(len(veh)):
            v = veh[k]
            x, y, z = pts[v]
            dx = x - sx
            dy = y - sy
            dz = z - sz
            d = math.sqrt((dx * dx + dz * dz) + dy * dy)
            reached = src_known and alive[k] and known[v] and d <= hi and (lo <= 0 or d >= lo)
            ok.append(reached)
            if k == own:                      # half duplex: my own signal occupies my receiver
                dist.append(0.0)
                delay.append(0.0)
            elif reached:
                dist.append(d)
                t = base + per_m * d
                delay.append(t)
                if t > longest:
                    longest = t
            else:
                dist.append(d)
                delay.append(INF)
        return dist, delay, ok, longest

    def _geometry_arrays(self, sender: Modem, now: float) -> Geometry:
        """A large channel's geometry with numpy: the same doubles as `_geometry_lists`."""
        import numpy as np

        poses = self.poses
        pos = poses.positions(now)
        mem = self._members_np
        if mem is None or mem[0] != self._members:
            mem = self._members_np = (self._members, np.array(self._veh, dtype=np.intp),
                                      np.array(self._alive, dtype=bool))
        veh = mem[1]
        sl = self._slots
        if sl is None or sl[0] != poses.version or sl[1] != self._members:
            sl = self._slots = (poses.version, self._members, mem[2] & poses.known_mask()[veh],
                                None if poses.moving else pos[veh])
        slot_ok, slot_pos = sl[2], sl[3]
        diff = (pos[veh] if slot_pos is None else slot_pos) - pos[sender.vehicle_index]
        dx, dy, dz = diff[:, 0], diff[:, 1], diff[:, 2]
        d2 = dx * dx
        d2 += dz * dz
        d2 += dy * dy
        dist = np.sqrt(d2)
        if not poses.known[sender.vehicle_index]:
            ok = np.zeros(len(veh), dtype=bool)
        elif sender.min_distance > 0:
            ok = slot_ok & (dist >= sender.min_distance) & (dist <= sender.max_distance)
        else:                                 # dist >= 0 holds for every known position
            ok = slot_ok & (dist <= sender.max_distance)
        delay = np.where(ok, self.min_prop_s + self.prop_s_per_m * dist, INF)
        if sender.rx_channel is self:         # half duplex: my own signal occupies my receiver
            delay[sender.rx_slot] = 0.0
            dist[sender.rx_slot] = 0.0
        return dist, delay, ok, float(np.max(delay, where=ok, initial=0.0))

    def transmit(self, sender: Modem, frame: Frame, dur: float) -> None:
        """First bit of `frame` leaves `sender` now; work out every listener's reception."""
        now = self.sched.now
        self.transmissions += 1
        log = self.log
        horizon = now - self._longest
        while log and log[0].max_end <= horizon:
            log.popleft()
        if dur > self._longest:
            self._longest = dur

        dist, delay, ok, max_delay = self._geometry(sender, now)
        own = sender.rx_slot if sender.rx_channel is self else -1
        tx = Transmission(frame, sender, now, dur, delay, dist, now + dur + max_delay, own)
        sinr = self.sinr
        if sinr:
            tx.pow = self._powers(sender, dist)
        log.append(tx)

        if frame.dst != BROADCAST and not self._overhearing:    # the common case: one addressee, no listener
            j = self._by_addr.get(frame.dst, -1)
            if j < 0 or j == own:
                return
            if not ok[j]:
                self._unreachable(sender, frame, j, now, dist)
                return
            err = sender.error
            if err.by_distance:
                per = float(err.losses(dist[j:j + 1], frame.size)[0])
                lv = err.levels(dist[j:j + 1])
                if lv is not None:
                    tx.keep_details((j,), None, lv)
            else:
                ans = err.answer(Query(now, frame, dist[j:j + 1], (j,), self.poses, sender.vehicle_index, self._veh))
                per = float(ans.per[0])
                if ans.delay is not None:
                    delay = self._retime(tx, (j,), ans.delay)
                if ans.doppler is not None or ans.level_db is not None:
                    tx.keep_details((j,), ans.doppler, ans.level_db)
            end = float(delay[j]) + now + dur          # = (delay + now + dur)[j], the same double
            if sinr:
                self.sched.at(end, self._end_sinr_at, tx, j, sender.loss_random(), per, True)
            else:
                self.sched.at(end, self._end_at, tx, j, sender.loss_random() < per, True)
            return
        if frame.dst == BROADCAST:       # every listener is intended: overhearers are among them
            targets = [i for i, m in enumerate(self.listeners) if i != own and m is not None]
            intended = len(targets)
        else:
            j = self._by_addr.get(frame.dst, -1)
            targets = [j] if j >= 0 and j != own else []
            intended = len(targets)
            targets += [i for i in self._overhearing if i != own and i != j]
        if not targets:
            return

        if isinstance(ok, list):
            reach: Any = [ok[j] for j in targets]
            far: Any = [dist[j] for j in targets]
        else:
            reach = ok[targets]
            far = dist[targets]
        pers: Any = None
        err = sender.error
        if not any(reach):
            pass
        elif err.by_distance:
            pers = err.losses(far, frame.size)
            lv = err.levels(far)
            if lv is not None:
                tx.keep_details(targets, None, lv)
        else:
            ans = err.answer(Query(now, frame, far, targets, self.poses, sender.vehicle_index, self._veh))
            pers = ans.per
            if ans.delay is not None:
                delay = self._retime(tx, targets, ans.delay)
            if ans.doppler is not None or ans.level_db is not None:
                tx.keep_details(targets, ans.doppler, ans.level_db)
        rnd = sender.loss_random
        at = self.sched.at
        ends = None if isinstance(delay, list) else tx.end
        for n, j in enumerate(targets):
            if not reach[n]:
                if n < intended:
                    self._unreachable(sender, frame, j, now, dist)
                continue
            assert pers is not None             # some target is reached
            end = float(delay[j]) + now + dur if ends is None else float(ends[j])
            if sinr:
                at(end, self._end_sinr_at, tx, j, rnd(), float(pers[n]), n < intended)
            else:
                at(end, self._end_at, tx, j, bool(rnd() < pers[n]), n < intended)

    def _retime(self, tx: Transmission, targets: Any, delays: Any) -> Any:
        """A model gave its own propagation delays (nan: the straight path) for `targets`: `tx` gets its own
        copy of the delays (the sender's geometry is shared), and its last end moves with them."""
        dl = list(tx.dl) if isinstance(tx.dl, list) else tx.dl.copy()
        last = tx.max_end
        for n, j in enumerate(targets):
            v = float(delays[n])
            if v == v and dl[j] != INF:        # not nan, and the receiver is in range
                dl[j] = v
                if tx.t0 + tx.dur + v > last:
                    last = tx.t0 + tx.dur + v
        tx.dl = dl
        tx.max_end = last
        tx._arr = tx._end = None
        return dl

    def _unreachable(self, sender: Modem, frame: Frame, j: int, now: float, dist: Any) -> None:
        m = self.listeners[j]
        assert m is not None                    # targets are listeners still attached
        known = self.poses.known
        why = "nopose" if not (known[self._veh[j]] and known[sender.vehicle_index]) else "range"
        self.tracer.emit(now, "drop", self.id, m.id, frame, why, dist=float(dist[j]))
        m.phy_failed(frame, why)

    def _reception_end(self, tx: Transmission, j: int, lost: bool, intended: bool) -> None:
        """The last bit of `tx` reached slot j: decide its fate against everything else heard there."""
        modem = self.listeners[j]
        if modem is None:
            return
        a = tx.dl[j] + tx.t0
        e = a + tx.dur - TOUCH        # the end, less the touch margin (the same doubles as ever)
        col = False
        for g in self.log:
            if g is not tx:
                gd = g.dl
                if isinstance(gd, list):    # typed, as in `busy`
                    glist: list[float] = gd
                    if j < len(glist):
                        ga = glist[j] + g.t0
                        if ga < e and a < ga + g.dur - TOUCH:
                            col = True
                            break
                elif j < len(gd):
                    ga = gd[j] + g.t0
                    if ga < e and a < ga + g.dur - TOUCH:
                        col = True
                        break
        frame = tx.frame
        if not intended:
            if not (lost or col):
                modem.phy_overheard(frame, tx.rx(j))
            return
        if lost or col:
            reason = "mult" if (lost and col) else ("prop" if lost else "col")
            self.tracer.emit(self.sched.now, "drop", self.id, modem.id, frame, reason, dist=tx.rx(j))
            modem.phy_failed(frame, reason)
        else:
            modem.phy_received(frame, tx.rx(j))

    # -- SINR mode (capture) ------------------------------------------------------------------
    def _powers(self, sender: Modem, dist: Any) -> np.ndarray:
        """Received power of `sender` at every slot; cached while its geometry (the same array) holds."""
        hit = self._pow_cache.get(sender.id)
        if hit is not None and hit[0] is dist:
            return hit[1]
        p = cast("SinrLossModel", sender.error).received_power(dist)
        self._pow_cache[sender.id] = (dist, p)
        return p

    def _reception_end_sinr(self, tx: Transmission, j: int, u: float, per_snr: float, intended: bool) -> None:
        """SINR mode: the last bit of `tx` reached slot j; decide by its minimum SINR (phy.interference)."""
        modem = self.listeners[j]
        if modem is None:
            return
        a, e = tx.arr[j], tx.end[j]
        own = False
        spans = []
        for g in self.log:
            if g is not tx and j < len(g.arr) and g.arr[j] < e - TOUCH and a < g.end[j] - TOUCH:
                if g.sender.rx_slot == j and g.sender.rx_channel is self:
                    own = True                  # half duplex: transmitting while this frame arrives
                else:
                    spans.append((g.arr[j], g.end[j], g.powers[j]))
        per_sinr = per_snr
        if own:
            per_sinr = 1.0
        elif self.lock_first_db is not None and not self._acquired(tx, j):
            per_sinr = 1.0                      # never locked onto: lost (col), or to noise if it was alone
            if not spans:
                per_snr = 1.0
        elif spans and u >= per_snr:
            err = cast("SinrLossModel", tx.sender.error)
            sinr_db = min_sinr_db(tx.powers[j], err.noise_power, spans, a)
            thr = self.sinr_threshold_db
            if thr is not None:
                per_sinr = 1.0 if sinr_db < thr else per_snr
            else:
                per_sinr = max(per_snr, float(err.per_from_sinr(sinr_db, tx.frame.size)))
        reason = classify(u, per_snr, per_sinr, own or bool(spans))
        frame = tx.frame
        if not intended:
            if reason is None:
                modem.phy_overheard(frame, tx.rx(j))
            return
        if reason is not None:
            self.tracer.emit(self.sched.now, "drop", self.id, modem.id, frame, reason, dist=tx.rx(j))
            modem.phy_failed(frame, reason)
        else:
            if spans:
                self.captures += 1
            modem.phy_received(frame, tx.rx(j))

    def _acquired(self, g: Transmission, j: int) -> bool:
        """Capture "first": did slot j lock onto `g` when it arrived?  Only if it was not transmitting, not
        locked onto an earlier frame still arriving, and g's SINR at that instant exceeded lock_first_db
        (ns-3 UanPhyGen::StartRxPacket).  Memoised per (transmission, slot)."""
        memo = g.acq
        if memo is None:
            memo = g.acq = {}
        hit = memo.get(j)
        if hit is not None:
            return hit
        a = g.arr[j]
        interference = 0.0
        ok = True
        for h in self.log:
            if h is g or j >= len(h.arr) or not (h.arr[j] <= a < h.end[j]):
                continue
            if h.sender.rx_slot == j and h.sender.rx_channel is self:
                ok = False                      # transmitting: cannot start receiving
                break
            if h.arr[j] < a and self._acquired(h, j):
                ok = False                      # already locked onto h
                break
            interference += h.powers[j]
        if ok:
            noise = cast("SinrLossModel", g.sender.error).noise_power
            ok = 10.0 * math.log10(g.powers[j] / (noise + interference)) > cast(float, self.lock_first_db)
        memo[j] = ok
        return ok

    # -- carrier sense -------------------------------------------------------------------------
    def _heard(self, g: Transmission, slot: int, t: float) -> bool:
        """Is `g` energy at `slot` at time t?  (A modem does not sense its own transmission.)"""
        if slot >= len(g.dl):
            return False
        a = g.dl[slot] + g.t0
        return a <= t < a + g.dur - TOUCH and g.own != slot

    def busy(self, slot: int) -> bool:
        t = self.sched.now
        for g in self.log:
            d = g.dl
            if isinstance(d, list):     # a small channel: typed, so compiled it adds doubles (no float objects)
                dlist: list[float] = d
                if slot < len(dlist):
                    a = dlist[slot] + g.t0
                    if a <= t < a + g.dur - TOUCH and g.own != slot:
                        return True
            elif slot < len(d):
                a = d[slot] + g.t0
                if a <= t < a + g.dur - TOUCH and g.own != slot:
                    return True
        return False

    def busy_until(self, slot: int) -> float:
        """When the energy heard at `slot` now ends, following overlaps (now if the channel is idle)."""
        t = self.sched.now
        log = self.log
        while True:
            last = -INF
            for g in log:
                if g.own == slot:
                    continue
                d = g.dl
                if isinstance(d, list):     # typed, as in `busy`: doubles, no float objects
                    dlist: list[float] = d
                    if slot >= len(dlist):
                        continue
                    a = dlist[slot] + g.t0
                elif slot < len(d):
                    a = float(d[slot] + g.t0)
                else:
                    continue
                end = a + g.dur
                if a <= t < end - TOUCH and end > last:
                    last = end
            if last == -INF:
                return t
            t = last
