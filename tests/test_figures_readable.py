"""Figures readable as the paper's (issue #20): the Fig. 3 FIFO panel shows a level, not a solid block;
Fig. 7 marks "nothing delivered" instead of drawing it like a value of 0; a protocol has one colour in
every figure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.colors import to_hex

from uwsimnet_zenoh.analysis import figures
from uwsimnet_zenoh.analysis.figures import fifo_bins, protocol_colour
from uwsimnet_zenoh.analysis.metrics import FlowMetrics


def test_fifo_bins_are_the_time_weighted_mean_and_the_max():
    t = np.array([1.0, 2.0, 3.0, 4.0])
    f = np.array([10, 0, 30, 0])
    b, mean, mx = fifo_bins(t, f, 0.0, 5.0, 5)
    assert list(b) == [0, 1, 2, 3, 4] and list(mean) == [0, 10, 0, 30, 0] and list(mx) == [0, 10, 0, 30, 0]
    # a frame every 0.16 s that fills the FIFO for 0.04 s: mean 25 % of full, max full
    t = np.sort(np.concatenate([np.arange(0, 10, 0.16), np.arange(0, 10, 0.16) + 0.04]))
    f = np.tile([30, 0], len(t) // 2)
    _, mean, mx = fifo_bins(t, f, 0.0, 9.6, 12)
    assert mean == pytest.approx(np.full(12, 7.5), abs=0.01) and set(mx) == {30.0}


def fifo_trace(n_frames: int) -> list[dict]:
    """A 100 s trace of `n_frames` frames of one flow, each filling the FIFO until it goes on air."""
    recs = [{"ev": "meta", "t": 0.0, "version": 1, "duration": 100.0}]
    for k in range(n_frames):
        t = k * 100.0 / n_frames
        recs += [{"t": t, "ev": "enq", "ch": 0, "dev": "a", "src": 1, "dst": 2, "seq": k, "size": 30, "flow": "f",
                  "kind": "data", "fifo": 30},
                 {"t": t + 0.01, "ev": "tx", "ch": 0, "dev": "a", "src": 1, "dst": 2, "seq": k, "size": 30,
                  "flow": "f", "kind": "data", "fifo": 0}]
    return recs


def test_a_busy_fifo_is_drawn_as_mean_and_max_not_thousands_of_steps(tmp_path, monkeypatch):
    drawn = {}
    real = figures._panel_fifo

    def spy(ax, c, *a):
        real(ax, c, *a)
        drawn["lines"] = [(ln.get_label(), len(ln.get_xdata())) for ln in ax.get_lines()]
        drawn["bands"] = [p.get_label() for p in ax.collections]
    monkeypatch.setattr(figures, "_panel_fifo", spy)
    for n in (50, 2000):
        p = tmp_path / f"t{n}.jsonl"
        p.write_text("\n".join(json.dumps(r) for r in fifo_trace(n)) + "\n")
        figures.plot_trace(p, tmp_path / f"f{n}")
        if n == 50:      # few steps: drawn as they are
            assert drawn["lines"] == [("a", 100)] and drawn["bands"] == []
        else:            # many: one mean line of FIFO_BINS steps and a max band, labelled so
            assert drawn["lines"] == [("a: mean per 1 s", figures.FIFO_BINS + 1)]
            assert drawn["bands"] == ["a: max per 1 s"]


def metrics(delivered: dict[str, int]) -> dict[str, FlowMetrics]:
    out = {}
    for name, n in delivered.items():
        m = FlowMetrics(name=name, src="a", dst=2)
        m.delivered = n
        if n:
            m.throughput, m.efficiency, m.delay_mean, m.jitter = 10.0, 0.5, 0.2, 0.01
        else:
            m.throughput = 0.0
        out[name] = m
    return out


def test_fig7_marks_nothing_delivered_and_keeps_protocol_colours(tmp_path, monkeypatch):
    captured = []
    real_save = figures._save

    def save(fig, path):
        captured.append(fig)
        return real_save(fig, path)
    monkeypatch.setattr(figures, "_save", save)
    runs = {"SFAMA": metrics({"f1": 5, "f2": 0}), "NOMAC": metrics({"f1": 0, "f2": 3})}
    figures.plot_compare(runs, tmp_path)
    ax_thr, _, ax_delay, _ = captured[0].axes
    bars = {to_hex(r.get_facecolor()) for r in ax_delay.patches}
    assert bars == {to_hex("tab:green"), to_hex("tab:blue")}      # SFAMA green, NOMAC blue, whatever the order
    for ax in (ax_thr, ax_delay):
        marks = [ln for ln in ax.get_lines() if ln.get_marker() == "x" and len(ln.get_xdata())]
        assert sorted((to_hex(ln.get_color()), len(ln.get_xdata())) for ln in marks) == \
            sorted([(to_hex("tab:green"), 1), (to_hex("tab:blue"), 1)])
    assert "nothing delivered (no value, not 0)" in [t.get_text() for t in ax_thr.get_legend().get_texts()]
    captured.clear()
    figures.plot_compare({"ALOHA": metrics({"f1": 5})}, tmp_path / "b")            # one label, same colour
    ax = captured[0].axes[0]
    assert {to_hex(r.get_facecolor()) for r in ax.patches} == {to_hex("tab:orange")}
    assert "nothing delivered" not in " ".join(t.get_text() for t in ax.get_legend().get_texts())


@pytest.mark.parametrize("label,colour", [("NOMAC", "tab:blue"), ("none", "tab:blue"), ("ALOHA", "tab:orange"),
                                          ("CS-ALOHA", "tab:orange"), ("SFAMA", "tab:green"),
                                          ("S-FAMA", "tab:green"), ("slotted-aloha", "tab:purple")])
def test_protocol_colours_are_fixed(label, colour):
    assert protocol_colour(label) == colour


def test_fig9_uses_the_fig7_colours():
    from uwsimnet_zenoh.experiments.hil_spec import PROTOCOLS
    from uwsimnet_zenoh.experiments.twinbot import PROTOCOLS as TWINBOT

    fig7 = {key: protocol_colour(label) for key, (_, label) in TWINBOT.items()}
    assert {mac: protocol_colour(label) for mac, label in PROTOCOLS.items()} == \
        {"aloha": fig7["aloha"], "sfama": fig7["sfama"]}
