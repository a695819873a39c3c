"""The phy-layer figures docs/ embeds are what `python -m uwsimnet_zenoh.experiments.phy_layer docs/figures`
draws now: compared by the numbers each PNG carries (frames per row, received per flow, the delay peak, the
FIFO's maximum), not by pixels."""

from __future__ import annotations

from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis.figures import figure_numbers
from uwsimnet_zenoh.experiments.phy_layer import DOC_FIGURES, doc_figures

DOCS = Path(__file__).resolve().parents[1] / "docs" / "figures"


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> dict[str, dict]:
    out = tmp_path_factory.mktemp("figs")
    return {p.name: figure_numbers(p) for p in doc_figures(out, tmp_path_factory.mktemp("work"))}


@pytest.mark.parametrize("name", sorted(DOC_FIGURES.values()))
def test_committed_figure_has_the_numbers_of_a_new_run(drawn, name):
    committed = figure_numbers(DOCS / name)
    assert committed, f"docs/figures/{name} carries no numbers: regenerate it"
    assert committed == drawn[name]


def test_the_acoustic_figure_says_the_papers_peak_and_this_runs(drawn):
    n = drawn["paper-phy-acoustic-fig4.png"]
    assert n["received"] == {"rov0-to-rov1": 329, "rov1-to-rov0": 24}
    assert n["peak_s"] == pytest.approx(0.253, abs=1e-3) and n["refs"][0][0] == 0.43
    fifo = drawn["paper-phy-rf-fig3.png"]["fifo_max_bytes"]
    assert max(fifo.values()) == 30.0            # one 30-byte frame of a 512-byte FIFO, never more
