"""The figures docs/paper-*.md embed, checked by number, not by pixels.

The phy-layer ones are what `python -m uwsimnet_zenoh.experiments.phy_layer docs/figures` draws now (the numbers
each PNG carries: frames per row, received per flow, the delay peak, the FIFO's maximum).  The TWINBOT and HIL
ones (`python -m uwsimnet_zenoh.experiments.doc_figures twinbot|table1|hil docs/figures`) carry a JSON sidecar:
the tables their pages state must be those numbers; the Fig. 7 runs and the HIL model are re-run (seconds), the
saturation search and the real-time runs (minutes) are not, their sidecars are checked for consistency."""

from __future__ import annotations

from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis.figures import figure_numbers
from uwsimnet_zenoh.analysis.intervals import label, mean_ci, ratio_ci
from uwsimnet_zenoh.experiments import doc_figures, hil_formation, sidecar, table1
from uwsimnet_zenoh.experiments.phy_layer import DOC_FIGURES
from uwsimnet_zenoh.experiments.phy_layer import doc_figures as phy_doc_figures

DOCS = Path(__file__).resolve().parents[1] / "docs" / "figures"


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> dict[str, dict]:
    out = tmp_path_factory.mktemp("figs")
    return {p.name: figure_numbers(p) for p in phy_doc_figures(out, tmp_path_factory.mktemp("work"))}


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


# -- the TWINBOT and HIL figures (experiments/doc_figures.py): sidecars, and the tables the pages state ------------
PAGES = Path(__file__).resolve().parents[1] / "docs"


def _page(name: str) -> str:
    """A page with each line's indentation removed (a table inside a list item is indented)."""
    return "\n".join(line.strip() for line in (PAGES / name).read_text(encoding="utf-8").splitlines())


def test_the_fig7_figures_are_what_their_command_draws_now(tmp_path):
    """`doc_figures twinbot` (the default profile with the Poisson variant, and the original profile: 9 runs of
    600 virtual seconds) gives the committed sidecars number for number."""
    (tmp_path / "figs").mkdir()
    drawn = doc_figures.twinbot_figures(tmp_path / "figs", tmp_path / "work", variants=("poisson",))
    assert [p.name for p in drawn] == list(doc_figures.TWINBOT_FIGURES.values())
    for p in drawn:
        assert sidecar.read(p) == sidecar.read(DOCS / p.name), p.name


@pytest.mark.parametrize("name", sorted(doc_figures.page_tables(DOCS)))
def test_every_table_the_pages_state_is_their_figures_numbers(name):
    page = _page("paper-hil.md" if "hil" in name else "paper-twinbot.md")
    for table in doc_figures.page_tables(DOCS)[name]:
        assert table in page, f"{name}: this table is not in the page (regenerate it with doc_figures tables):\n{table}"


def test_table1_intervals_and_labels_follow_from_the_per_seed_maxima():
    """The committed Table 1 sidecars: each mean and interval is the t interval of its five per-seed maxima, each
    ratio the interval of the per-seed ratios, each label what `label` says of the paper's ratio."""
    labels = {}
    for profile, name in doc_figures.TABLE1_FIGURES.items():
        num = sidecar.read(DOCS / name)
        assert num["seeds"] == [1, 2, 3, 4, 5] and num["profile"] == profile
        for p, chans in num["found"].items():
            for ch, c in chans.items():
                iv = mean_ci(list(c["per_seed_Bps"].values()))
                assert c["mean_Bps"] == pytest.approx(iv.mean, abs=1e-6)
                assert c["half_Bps"] == pytest.approx(iv.half, abs=1e-6)
                assert label(iv, c["paper_Bps"]) == "not", (profile, p, ch)     # no maximum is the paper's
        for ch, r in num["ratios"].items():
            a, s = num["found"]["aloha"][ch]["per_seed_Bps"], num["found"]["sfama"][ch]["per_seed_Bps"]
            iv = ratio_ci([a[k] for k in a], [s[k] for k in a])
            assert (r["mean"], r["half"]) == (pytest.approx(iv.mean, abs=1e-6), pytest.approx(iv.half, abs=1e-6))
            labels[(profile, ch)] = r["label"]
            assert r["label"] == label(iv, {"RF": 62.5 / 27.5, "acoustic": 30 / 27.5}[ch])
    assert labels == {("default", "RF"): "reproduced", ("default", "acoustic"): "reproduced",
                      ("original", "RF"): "not", ("original", "acoustic"): "reproduced"}
    for name in doc_figures.TABLE1_FIGURES.values():         # the figure's numbers are a function of the maxima
        num = sidecar.read(DOCS / name)
        assert sidecar._rounded(table1.numbers(num)) == num


def test_the_hil_model_rows_and_the_over_seeds_tables_are_what_the_model_gives_now():
    """The virtual-time model is deterministic per seed: its timing rows in the committed Fig. 9 sidecars, and the
    `--virtual` over-seeds tables of docs/paper-hil.md, from a new run of the model (20 runs of 240 s)."""
    page = _page("paper-hil.md")
    for traffic, name in doc_figures.HIL_FIGURES.items():
        committed = sidecar.read(DOCS / name)
        assert committed["traffic"] == traffic and committed["duration"] == hil_formation.DURATION
        for mac in ("aloha", "sfama"):
            now = hil_formation.stats(hil_formation.simulate(mac, traffic=traffic))["timing"]
            assert sidecar._rounded(now) == committed["virtual"][mac]["timing"], (traffic, mac)
        for text in doc_figures.hil_seeds_tables(hil_formation.over_seeds(traffic, hil_formation.DURATION)):
            assert text in page, f"{traffic}: not in docs/paper-hil.md:\n{text}"
