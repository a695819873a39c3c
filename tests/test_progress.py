"""Progress of long runs shows when the output is piped: plain lines, not a bar that prints nothing."""

from __future__ import annotations

import io

from uwsimnet_zenoh.experiments.processes import Progress


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_piped_progress_is_plain_lines():
    out = io.StringIO()
    with Progress("run", total=40, stream=out, every=0.0) as bar:
        for t in (10, 20, 30, 40):
            bar.update(t)
    lines = out.getvalue().splitlines()
    assert lines == ["run: 0/40 s (0%)", "run: 10/40 s (25%)", "run: 20/40 s (50%)", "run: 30/40 s (75%)",
                     "run: 40/40 s (100%)"]


def test_piped_progress_is_rate_limited():
    out = io.StringIO()
    with Progress("run", total=1000, stream=out, every=3600.0) as bar:
        for t in range(1000):
            bar.update(t)
    assert out.getvalue().splitlines() == ["run: 0/1000 s (0%)", "run: 999/1000 s (100%)"]


def test_a_terminal_gets_the_bar():
    out = Tty()
    with Progress("run", total=10, stream=out) as bar:
        assert bar._bar is not None
        bar.update(5)
    assert "run: 0/10" not in out.getvalue()
