"""A run's outputs, assembled once for the virtual and the realtime clock: the listeners of its output port
(trace/tracer.py) that `uwsimnet run` asks for.

    with Outputs(net, meta, trace_path, plugin=tracing_sink(scene)) as out:
        net.run()                       # (or the realtime clock's thread)
        out.finish(net.end_record(...)) # the last batch, the end record last in the trace
    out.result()                        # the online metrics' Analysis

In order: the trace writer if a path is given (JSONL, `.gz` compressed, `.arrow` columnar: renderings of the
one record, written from the port's batches), the scene's tracing plug-in (records), then the online metrics
(after the writer, so that they share its batches: analysis.Accumulator.follow).  Leaving the `with`, even
on an error or ^C, the last batch is written and the file closed whole.  The realtime broker adds its own
listener (bus/broker.py); the simulator backend (drivers/sim_backend.py: `SimWorld(trace=..., metrics=...)`)
takes the same outputs beside its own listener.
"""

from __future__ import annotations

import gzip
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from ..analysis import Accumulator, Analysis
from ..analysis.read import DEFAULT_HORIZON
from ..engine.network import Network
from ..errors import UserError
from ..trace.events import ArrowSink, CallbackSink, JsonlSink


class Outputs:
    def __init__(self, net: Network, meta: dict[str, Any], trace_path: str | Path | None = None, *,
                 metrics: bool = True, plugin: CallbackSink | None = None) -> None:
        self.net = net
        self.meta = meta
        self.trace_path = None if trace_path is None else Path(trace_path)
        self.plugin = plugin
        self.acc = Accumulator(meta, settle_after=DEFAULT_HORIZON) if metrics else None  # bounded memory
        self.jsonl: JsonlSink | None = None
        self._fh: Any = None
        self._files = ExitStack()

    def __enter__(self) -> Outputs:
        tracer, files, path = self.net.tracer, self._files, self.trace_path
        try:
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                if path.suffix == ".arrow":
                    try:
                        arrow = ArrowSink(path, self.meta)
                    except ValueError as e:
                        raise UserError(f"{path}: {e}") from None
                    files.callback(arrow.close)
                    tracer.consume(arrow.write_batch)
                else:
                    opener = gzip.open if path.suffix == ".gz" else open
                    self._fh = files.enter_context(opener(path, "wb"))
                    self.jsonl = JsonlSink(self._fh)
                    files.callback(self.jsonl.flush)    # before the file closes (an ExitStack unwinds in reverse)
                    self.jsonl.header(self.meta)
                    tracer.consume(self.jsonl.write_batch)
            if self.plugin is not None:
                tracer.add(self.plugin)
            if self.acc is not None:
                self.acc.follow(tracer)                 # after the writers: it shares their batches
            files.callback(tracer.flush)                # the last batch, before the writers close (^C ^C too)
        except BaseException:
            files.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self._files.close()

    def flush(self) -> None:
        """The pending events to the writers, and the trace file to disk (realtime: every second, so that
        `tail -f` follows it)."""
        self.net.tracer.flush()
        if self.jsonl is not None:
            self.jsonl.flush()
        if self._fh is not None:
            self._fh.flush()

    def finish(self, end: dict[str, Any] | None) -> None:
        """The run is over: the last batch, then the `end` record (if the run has one) last in the trace."""
        self.net.tracer.flush()
        if end is not None:
            if self.jsonl is not None:
                self.jsonl(end)
            if self.acc is not None:
                self.acc.ended = end["t"]

    def result(self) -> Analysis | None:
        """The online metrics of the run (None without them)."""
        return self.acc.result() if self.acc is not None else None
