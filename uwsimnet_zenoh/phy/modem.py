"""A simulated modem (ns-3's NetDevice + Phy): tx FIFO, timing, duplex, and the glue to its MAC.

Timing of one frame (docs/phy-model.md):
    enq ──FIFO wait──▶ taken by the MAC ──intrinsic tx delay + jitter──▶ tx (first bit on air)
        ──propagation (at tx start)──▶ first bit at receiver ──8·L/bitrate──▶ last bit
        ──intrinsic rx delay + jitter──▶ rx (delivered to the application, in order)
The transmitter is busy from the moment it takes the frame until the last bit leaves.  Jitter is a
Gaussian added to the intrinsic delay, truncated so the total never goes below zero.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from ..kernel.frame import BROADCAST, Frame
from ..kernel.link import MacHooks, Medium

if TYPE_CHECKING:
    from ..kernel.scheduler import Event, Scheduler
    from ..trace.tracer import Tracer

class DeviceParams(Protocol):
    """The device parameters a modem reads (`scene.model.Device` has them; phy never imports the scene)."""

    dccomms_id: str
    address: int
    bitrate: float
    header_bytes: int
    min_distance: float
    max_distance: float
    tx_fifo_bytes: int
    max_frame_bytes: int
    intrinsic_tx_s: float
    intrinsic_rx_s: float
    jitter_tx_s: float
    jitter_rx_s: float
    tx_framing: str | None          # a dccomms packet builder (phy.framing), or None: no framing


class LossModel(Protocol):
    """What the channel asks a transmitter's channel model (phy.models.ChannelModel): one answer for all the
    receivers of a transmission."""

    @property
    def by_distance(self) -> bool: ...
    def losses(self, distances: Any, size: int) -> Any: ...
    def levels(self, distances: Any) -> Any: ...
    def answer(self, q: Any) -> Any: ...


class SinrLossModel(LossModel, Protocol):
    """What a channel in SINR mode also asks (phy.acoustic's models have it): received power at each
    distance, the noise power, and the packet error rate at a given SINR."""

    @property
    def noise_power(self) -> float: ...
    def received_power(self, distance_m: Any) -> Any: ...
    def per_from_sinr(self, sinr_db: float, size_bytes: int) -> Any: ...


class Modem:
    """One device: built by the engine's build step, which gives it its loss model and then its MAC
    (`attach_mac`) before the first frame.  It is its MAC's context (it has kernel.link.MacContext's shape)
    and calls it through `MacHooks` (mac.Mac is one): phy never imports mac.  Compiled (a native class),
    so it names no Protocol as a base."""

    def __init__(self, cfg: DeviceParams, vehicle: str, vehicle_index: int, sched: Scheduler, tracer: Tracer,
                 tx_channel: Medium, rx_channel: Medium, seeds: Callable[[str, str], int],
                 error: LossModel) -> None:
        self.cfg = cfg
        self.id = cfg.dccomms_id
        self.address = cfg.address
        self.vehicle = vehicle
        self.vehicle_index = vehicle_index
        self.sched = sched
        self.tracer = tracer
        self.tx_channel = tx_channel
        self.rx_channel = rx_channel
        self._tx_ch = tx_channel.id                   # the channel ids its events carry (read once)
        self._rx_ch = rx_channel.id
        self.bitrate = cfg.bitrate
        self.header_bytes = cfg.header_bytes
        name = getattr(cfg, "tx_framing", None)
        self.framing: Any = None        # a phy.framing.Framing (imported by the few devices that frame)
        if name:
            from .framing import builder
            self.framing = builder(name)
        """The dccomms framing of what this modem sends: its framed size goes on air (dccomms_ros puts
        `GetPacketSize()` in the NetsimHeader the channel times frames with)."""
        self.min_distance = cfg.min_distance
        self.max_distance = cfg.max_distance
        self.error = error
        self.fifo: deque[Frame] = deque()
        self.fifo_bytes = 0
        self.fifo_cap = cfg.tx_fifo_bytes
        self.max_frame_bytes = cfg.max_frame_bytes
        self.tx_delay = cfg.intrinsic_tx_s            # the per-frame path reads these (a device never changes)
        self._tx_jitter = cfg.jitter_tx_s
        self._rx_delay = cfg.intrinsic_rx_s
        self._rx_jitter = cfg.jitter_rx_s
        self.phy_busy = False
        self.closed = False
        self.half_duplex = tx_channel is rx_channel
        self._seq = 0
        self._last_delivery = 0.0
        self.loss_random = random.Random(seeds("loss", self.id)).random
        self._jitter = random.Random(seeds("jitter", self.id))
        self.random = random.Random(seeds("mac", self.id)).random
        self.enqueued = 0               # frames offered, transmissions, deliveries, drops (`counters`)
        self.transmitted = 0
        self.delivered = 0
        self.dropped = 0
        self.mac: MacHooks = _NO_MAC
        self.rx_slot = -1
        # the scheduled steps, bound once: a bound method made per event is a lookup by name and an object
        self._on_air_at: Callable[[Frame], None] = self._on_air
        self._tx_end_at: Callable[[Frame], None] = self._tx_end
        self._deliver_at: Callable[[Frame, Any], None] = self._deliver

    @property
    def counters(self) -> dict[str, int]:
        """Frames so far: offered (enq), transmitted (tx), delivered (rx) and dropped (drop); a copy."""
        return {"enq": self.enqueued, "tx": self.transmitted, "rx": self.delivered, "drop": self.dropped}

    def on_air_size(self, payload: int) -> int:
        """Bytes on air for `payload` bytes of data: the framed size (if the device has a framing) plus
        the device's headerBytes."""
        framed = self.framing.frame_size(payload) if self.framing is not None else payload
        return framed + self.header_bytes

    def attach_mac(self, mac: MacHooks) -> None:
        """Give the modem its MAC (built with this modem as its context), then listen on the rx channel."""
        self.mac = mac
        self.rx_slot = self.rx_channel.attach(self)

    @property
    def overhears(self) -> bool:
        """Whether the channel must hand this modem intact frames addressed to others (its MAC asks)."""
        return bool(getattr(self.mac, "overhear", False))     # by name: a Python MAC's class attribute

    # -- the application side ------------------------------------------------------------------
    def send(self, dst: int, payload: int, *, data: bytes | None = None, flow: str | None = None,
             tag: Any = None, refuse: str | None = None, msg: dict | None = None) -> Frame:
        """An application (or flow) offers `payload` bytes for `dst`; the frame ends traced either way.

        `refuse`: the caller knows the modem cannot take the frame (the bus: its vehicle has no pose
        yet); it is traced as enq then dropped at the transmitter with that reason.  `msg`: the sender
        device's description of the message (Frame.msg), carried to the receivers untouched."""
        now = self.sched.now
        size = payload + self.header_bytes if self.framing is None else self.on_air_size(payload)
        frame = Frame(self.address, dst, self._seq, size, payload, data=data,
                      flow=flow, t_enq=now, tag=tag, dev=self.id, msg=msg)
        self._seq += 1
        self.enqueued += 1
        mac = self.mac
        direct = not self.fifo and mac.ready()
        if refuse is None:
            if self.closed:
                refuse = "removed"
            elif size > self.max_frame_bytes or 0 < self.fifo_cap < size or (
                    self.framing is not None and self.framing.check_payload(payload) is not None):
                refuse = "size"             # (larger than its FIFO: refused idle or busy alike, #41)
            elif dst != BROADCAST and not getattr(mac, "implicit_broadcast", False) \
                    and not self.tx_channel.has_address(dst):
                refuse = "noaddr"           # nobody on the channel has that address: say so now
        if refuse is not None:
            self.tracer.emit(now, "enq", self._tx_ch, self.id, frame, fifo=self.fifo_bytes)
            self.drop(frame, refuse)
        elif not direct and self.fifo_bytes + size > self.fifo_cap:
            self.tracer.emit(now, "enq", self._tx_ch, self.id, frame, fifo=self.fifo_bytes)
            self.drop(frame, "fifo")
        else:
            self.tracer.emit(now, "enq", self._tx_ch, self.id, frame, None,
                             self.fifo_bytes + (0 if direct else size))
            self.fifo.append(frame)
            self.fifo_bytes += size
            if self.tracer.watchers:
                self.status(frame, "queued")
            mac.on_queue()
        return frame

    # -- what the MAC may do (MacContext) -------------------------------------------------------
    @property
    def now(self) -> float:
        return self.sched.now

    def timer(self, delay: float, fn: Callable[..., Any], *args: Any) -> Event:
        return self.sched.after(delay, fn, *args)

    def fifo_peek(self) -> Frame | None:
        return self.fifo[0] if self.fifo else None

    def fifo_pop(self) -> Frame | None:
        if not self.fifo:
            return None
        frame = self.fifo.popleft()
        self.fifo_bytes -= frame.size
        return frame

    def transmit(self, frame: Frame, delay: float | None = None) -> None:
        """Hand `frame` to the PHY: first bit on air after the intrinsic delay (and jitter), or after
        `delay` s instead (a queued frame in dccomms_ros: 100 us after the previous one, no intrinsic delay)."""
        if self.phy_busy:
            raise RuntimeError(f"{self.id}: transmit while the transmitter is busy ({frame})")
        self.phy_busy = True
        frame.tries += 1
        if delay is not None:
            d = delay
        else:
            d = self.tx_delay
            if self._tx_jitter > 0:
                d = max(0.0, self._jitter.gauss(d, self._tx_jitter))
        if d > 0:
            self.sched.after(d, self._on_air_at, frame)
        else:
            self._on_air(frame)

    def _on_air(self, frame: Frame) -> None:
        now = self.sched.now
        frame.t_tx = now
        self.transmitted += 1
        self.tracer.emit(now, "tx", self._tx_ch, self.id, frame, None, self.fifo_bytes)
        dur = frame.size * 8.0 / self.bitrate
        self.tx_channel.transmit(self, frame, dur)
        self.sched.at(now + dur, self._tx_end_at, frame)       # = after(dur): the same double

    def _tx_end(self, frame: Frame) -> None:
        self.phy_busy = False
        self.mac.on_tx_done(frame)

    def channel_busy(self) -> bool:
        return self.rx_channel.busy(self.rx_slot)

    def channel_busy_until(self) -> float:
        return self.rx_channel.busy_until(self.rx_slot)

    def deliver(self, frame: Frame, rx: Any) -> None:
        d = self._rx_delay
        if self._rx_jitter > 0:
            d = max(0.0, self._jitter.gauss(d, self._rx_jitter))
        t = max(self.sched.now + d, self._last_delivery)   # a modem hands frames up in order
        self._last_delivery = t
        if t > self.sched.now:
            self.sched.at(t, self._deliver_at, frame, rx)
        else:
            self._deliver(frame, rx)

    def _deliver(self, frame: Frame, rx: Any) -> None:
        now = self.sched.now
        self.delivered += 1
        # a frame for another address handed up anyway (no MAC: the original's implicit broadcast)
        implicit = frame.dst != BROADCAST and frame.dst != self.address
        self.tracer.emit(now, "rx", self._rx_ch, self.id, frame, dist=rx, implicit=implicit)

    def drop(self, frame: Frame, reason: str, event: str = "dropped") -> None:
        """Give `frame` up: traced `drop` with `reason`, and its final status `event` (`dropped`; a MAC
        that gave up after its retries says `failed`)."""
        frame.final = reason
        self.dropped += 1
        self.tracer.emit(self.sched.now, "drop", self._tx_ch, self.id, frame, reason, self.fifo_bytes)
        if self.tracer.watchers:
            self.status(frame, event, reason)

    def status(self, frame: Frame, event: str, reason: str | None = None) -> None:
        """A status of `frame` for its sender (the output port's `status`)."""
        self.tracer.status(self.sched.now, event, self._tx_ch, self.id, frame, reason)

    def tx_time(self, size: int) -> float:
        return size * 8.0 / self.bitrate

    def trace_rx(self, frame: Frame, rx: Any) -> None:
        """A MAC control frame reached its MAC intact: traced as `rx`, not handed to the application."""
        self.tracer.emit(self.sched.now, "rx", self._rx_ch, self.id, frame, dist=rx)

    def max_prop_delay(self, distance: float | None = None) -> float:
        return self.tx_channel.max_prop_delay(self.max_distance if distance is None else distance)

    def ctrl_frame(self, dst: int, size: int, info: dict, about: Frame | None = None) -> Frame:
        """A MAC control frame (RTS, CTS, ACK): kind ctrl, counted for the flow it serves."""
        return Frame(self.address, dst, about.seq if about else -1, size, 0,
                     flow=about.flow if about else None, kind="ctrl", t_enq=self.sched.now,
                     dev=self.id, info=info)

    # -- the PHY side --------------------------------------------------------------------------
    def phy_received(self, frame: Frame, rx: Any) -> None:
        """Called by the channel: `frame` (for us or broadcast) arrived intact; `rx` the distance, with the
        channel model's details if it gave any (kernel.rx), which the MAC hands back with the frame."""
        self.mac.on_rx(frame, rx)

    def phy_overheard(self, frame: Frame, rx: Any) -> None:
        """Called by the channel: `frame`, addressed to another modem, arrived intact (if `overhears`)."""
        self.mac.on_overhear(frame, rx)

    def phy_failed(self, frame: Frame, reason: str) -> None:
        """Called by the channel: `frame`, addressed to us, was lost (prop, col, mult, range, nopose)."""
        self.mac.on_rx_error(frame, reason)

    def close(self) -> None:
        """Leave the simulation: every frame still held ends with a drop (reason `removed`)."""
        self.closed = True
        self.mac.close()
        while self.fifo:
            frame = self.fifo_pop()
            assert frame is not None
            self.drop(frame, "removed")
        self.rx_channel.detach(self)


class _Unattached:
    """The MAC of a modem the build step has not finished: using it is a wiring bug, said clearly."""

    def _bug(self, name: str) -> RuntimeError:
        return RuntimeError(f"modem used before the build step attached its MAC ({name})")

    def ready(self) -> bool:
        raise self._bug("ready")

    def on_queue(self) -> None:
        raise self._bug("on_queue")

    def on_tx_done(self, frame: Frame) -> None:
        raise self._bug("on_tx_done")

    def on_rx(self, frame: Frame, rx: Any) -> None:
        raise self._bug("on_rx")

    def on_overhear(self, frame: Frame, rx: Any) -> None:
        raise self._bug("on_overhear")

    def on_rx_error(self, frame: Frame, reason: str) -> None:
        raise self._bug("on_rx_error")

    def close(self) -> None:
        raise self._bug("close")


_NO_MAC = _Unattached()
