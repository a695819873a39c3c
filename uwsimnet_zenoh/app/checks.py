"""What `validate` and both run functions share, so that validation matches what runs.

* `build_network(scene, ...)`: the Network with every device's MAC and loss model built (the build step
  refuses unknown MAC parameters, plug-in MACs that do not import or do not subclass `Mac`); a
  failure is one line `file:line: message` (UserError, exit 2).
* `tracing_sink(scene)`: the scene's tracing plug-in (`netTracingScript className`), loaded and
  checked (it imports, is a class, implements at least one of on_enq/on_tx/on_rx/on_drop, can be
  created), or None; failures at the tracing element's line.
* `plugin_failure(sink)`: the one-line account of a tracing plug-in that raised during the run (it
  was disabled then; the run ends with exit code 2), or None.
* `StopOnSignal`-like `Interrupt` for virtual runs: SIGINT/SIGTERM end the run between two events.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

from ..engine.build import BuildError
from ..engine.network import Network
from ..errors import UserError
from ..trace.events import CallbackSink, load_tracing_class

EXIT_OK = 0
"""The run reached its duration, or was stopped on request (SIGINT/SIGTERM, end record reason `signal`)."""
EXIT_ERROR = 2
"""Bad input (one line on stderr), or the run was cut by an error: a plug-in (tracing class, MAC) or
the engine raised; the traceback is in the log, the trace ends with an `end` record reason `error`."""


def build_network(scene: Any, **kw: Any) -> Network:
    try:
        return Network(scene, **kw)
    except BuildError as e:
        raise UserError(f"{scene.source}:{e.line}: {e}") from None
    except ValueError as e:
        raise UserError(f"{scene.source}: {e}") from None


def tracing_sink(scene: Any) -> CallbackSink | None:
    spec = scene.tracing.class_name
    if not spec:
        return None
    try:
        return CallbackSink(load_tracing_class(spec), name=spec)
    except ValueError as e:
        raise UserError(f"{scene.source}:{scene.tracing.line}: {e}") from None


def plugin_failure(sink: CallbackSink | None) -> str | None:
    if sink is None or sink.failed is None:
        return None
    e = sink.failed
    return (f"tracing class {sink.name} raised {type(e).__name__}: {e} at t={sink.failed_at}; it was disabled"
            " for the rest of the run (traceback above)")


def failed_plugin(net: Network) -> str | None:
    """`plugin_failure` of the tracing plug-in among the listeners of `net`'s output port."""
    for lst in net.tracer.listeners:
        s = getattr(lst, "fn", None)        # (trace.tracer.Records: the plug-in takes records)
        if isinstance(s, CallbackSink) and s.failed is not None:
            return plugin_failure(s)
    return None


def check(scene: Any) -> None:
    """Everything `validate` can know without running: the scene file's checks (already done when
    loading), then the build step for every device and the tracing plug-in."""
    build_network(scene, flows=True)
    tracing_sink(scene)


class Interrupt:
    """SIGINT/SIGTERM during a virtual run: the scheduler stops between two events (the first signal);
    a second signal raises KeyboardInterrupt.  A no-op outside the main thread."""

    def __init__(self, net: Network) -> None:
        self.net = net
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum
        self.net.sched.interrupt()

    def __enter__(self) -> Interrupt:
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, *exc: Any) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old.clear()
