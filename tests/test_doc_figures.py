"""The figures docs/paper-*.md embed, checked by number, not by pixels.

The phy-layer ones are what `python -m uwsimnet_zenoh.experiments.phy_layer docs/figures` draws now (the numbers
each PNG carries: frames per row, received per flow, the delay peak, the FIFO's maximum).  The TWINBOT and HIL
ones (`python -m uwsimnet_zenoh.experiments.doc_figures twinbot|table1|hil docs/figures`) carry a JSON sidecar:
the tables their pages state must be those numbers; the Fig. 7 runs and the HIL model are re-run (seconds), the
saturation search and the real-time runs (minutes) are not, their sidecars are checked for consistency."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from uwsimnet_zenoh.analysis.figures import figure_numbers
from uwsimnet_zenoh.analysis.intervals import Interval, label, mean_ci, ratio_ci
from uwsimnet_zenoh.experiments import doc_figures, hil_formation, sidecar, table1, twinbot
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
        seeds = hil_formation.over_seeds(traffic, hil_formation.DURATION)
        for text in doc_figures.hil_seeds_tables(seeds):
            assert text in page, f"{traffic}: not in docs/paper-hil.md:\n{text}"
        iv = mean_ci(seeds["ratio_followers"])       # "comparable performance": a ratio of 1 is the paper's claim
        assert label(iv, 1.0) == "not" and f"{iv.mean:.2f} ± {iv.half:.2f}" in page, (traffic, iv)


def test_the_numbers_over_seeds_are_the_figures_runs_and_a_new_run():
    """figures/paper-twinbot-seeds.json (what the findings are labelled against): its seed 1 is the run of each
    profile's Fig. 7 (the committed sidecars), and seed 3 of each profile is what a new run gives."""
    seeds = json.loads((DOCS / doc_figures.SEEDS_FILE).read_text(encoding="utf-8"))
    assert list(seeds) == ["default", "original"]
    for profile, fig in (("default", "paper-twinbot-fig7.png"), ("original", "paper-twinbot-fig7-original.png")):
        assert seeds[profile]["seeds"] == list(doc_figures.TWINBOT_SEEDS)
        cells = seeds[profile]["protocols"]
        for p, r in sidecar.read(DOCS / fig)["protocols"].items():
            for n, f in r["flows"].items():
                for m in twinbot.SEED_METRICS:
                    assert cells[p][f"{n}/{m}"]["values"][0] == f[m], (profile, p, n, m)
        now = twinbot.over_seeds([3], profile)["protocols"]
        for p, c in now.items():
            for k, v in c.items():
                assert sidecar._rounded(v["values"])[0] == cells[p][k]["values"][2], (profile, p, k)


def test_the_labels_follow_from_the_intervals():
    """Each label of the tables is `label` (or the ordering rule) of the intervals printed beside it, re-read from
    the page's text: a label cannot disagree with the numbers it stands next to."""
    page = _page("paper-twinbot.md")
    cells = re.findall(r"\| ([-\d.]+) ± ([\d.]+) of ([\d.]+): (reproduced|not) ", page)
    assert len(cells) >= 32
    for mean, half, paper, lab in cells:
        assert label(Interval(10, float(mean), float(half)), float(paper)) == lab, (mean, half, paper, lab)
    rf = {"leader", "follower", "support"}
    flows = ["leader", "follower", "support", "buoy", "E0", "E1", "E2", "E3"]
    checked = 0
    for line in page.splitlines():
        row = [c.strip() for c in line.strip("|").split("|")]
        if len(row) != 10 or row[0] not in ("default", "original") or row[1] not in ("efficiency", "delay s",
                                                                                        "jitter s"):
            continue
        for flow, cell in zip(flows, row[2:], strict=True):
            m = re.fullmatch(r"([-\d.]+) ± ([\d.]+) / ([-\d.]+) ± ([\d.]+): (reproduced|not established|not)", cell)
            assert m, cell
            a_lo, a_hi = float(m[1]) - float(m[2]), float(m[1]) + float(m[2])      # CS-ALOHA
            s_lo, s_hi = float(m[3]) - float(m[4]), float(m[3]) + float(m[4])      # S-FAMA
            if row[1] == "jitter s":                                               # "comparable": they overlap
                want = "reproduced" if a_lo <= s_hi and s_lo <= a_hi else "not"
            else:       # S-FAMA lower delay; higher efficiency on the acoustic channel, lower on the RF one
                s_below = row[1] == "delay s" or flow in rf
                ok, wrong = (s_hi < a_lo, a_hi < s_lo) if s_below else (a_hi < s_lo, s_hi < a_lo)
                want = "reproduced" if ok else "not" if wrong else "not established"
            assert m[5] == want, (row[0], row[1], flow, cell)
            checked += 1
    assert checked == 2 * 3 * 8


def test_the_phy_layer_labels_follow_from_their_intervals():
    """docs/paper-phy-layer.md: each distance bin's "inside" is whether the BER expression's PER lies in the bin's
    Wilson interval, and the ≈430 ms peak is labelled against its (zero-width: no random draw) interval."""
    page = _page("paper-phy-layer.md")
    rows = re.findall(r"\| [\d.]+-[\d.]+ \| \d+ \| [\d.]+ \| ([\d.]+) - ([\d.]+) \| ([\d.]+) \| (yes|no) \|", page)
    assert len(rows) == 8
    for lo, hi, expected, inside in rows:
        assert (float(lo) <= float(expected) <= float(hi)) == (inside == "yes")
    row = next(line for line in page.splitlines() if line.startswith("| delay rises to ≈430 ms"))
    assert label(Interval(10, 252.8, 0.0), 430.0) == "not" and "252.8 ± 0" in row and "the value **not**" in row


def test_every_figure_a_paper_page_shows_has_a_command_and_its_numbers():
    """Each docs/figures/*.png that a docs/paper-*.md links or embeds is drawn by one of the commands (phy_layer's or
    doc_figures') and carries its numbers (in the PNG or a sidecar)."""
    shown = {m for page in PAGES.glob("paper-*.md")
             for m in re.findall(r"figures/([a-z0-9-]+\.png)", page.read_text(encoding="utf-8"))}
    made = {*DOC_FIGURES.values(), *doc_figures.TWINBOT_FIGURES.values(), *doc_figures.TABLE1_FIGURES.values(),
            *doc_figures.HIL_FIGURES.values()}
    assert shown == made
    for name in shown:
        assert figure_numbers(DOCS / name) or sidecar.read(DOCS / name), name


def test_the_phy_layer_stages_over_seeds_and_their_labels():
    """The RF run over seeds 1-10 per stage (a few seconds): the page's table is what it gives now, and the findings
    'both attenuation and collisions at 4.5 m' and 'only collisions at 3.3 m' follow from its intervals."""
    from uwsimnet_zenoh.app.api import run as run_one
    from uwsimnet_zenoh.experiments import phy_layer

    rf = phy_layer.reading_scene("rf")
    rows = phy_layer.stages_over_seeds([phy_layer.phases(run_one(rf, seed=s, trace=True).trace or [])
                                        for s in range(1, 11)])
    assert phy_layer.stages_table(rows) in _page("paper-phy-layer.md")
    cell = {(r["flow"], r["stage"]): {k: Interval(10, r[k]["mean"], r[k]["half"]) for k in phy_layer.STAGE_COUNTS}
            for r in rows}
    at45 = cell[("rov0-to-rov1", "both send, 4.5 m")]
    assert all(at45[k].low > 0 for k in ("prop", "col", "mult"))
    for flow in ("rov0-to-rov1", "rov1-to-rov0"):
        at33 = cell[(flow, "both send, 3.3 m")]
        assert label(at33["prop"], 0.0) == "reproduced" and at33["col"].low > 0


def test_the_command_refuses_what_it_does_not_know():
    """A wrong sub-command is a one-line usage error, exit 2, no traceback."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.experiments.doc_figures", "figures"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1 and r.stderr.startswith("usage:")


def _signed(x: str) -> float:
    return float(x.replace("−", "-").replace("+", ""))


def test_the_hil_real_time_intervals_are_those_of_the_runs_listed():
    """docs/paper-hil.md gives every real-time run's value beside its interval (real time can not be re-run number
    for number): each interval is the t interval of the values listed, each label what it says of the claim."""
    page = _page("paper-hil.md")
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in page.splitlines()
            if re.match(r"\| (CS-ALOHA|S-FAMA) \| (leader|followers) \| [-+−]", line)]
    assert [len(r) for r in rows] == [9] * 4 + [7] * 4          # paper traffic: 6 runs; control: 4
    for r in rows:
        m = re.match(r"\**([-+−\d.]+) ± ([\d.]+)\**( \(excludes 0)?", r[-1])
        iv = mean_ci([_signed(x) for x in r[2:-1]])
        assert m and (f"{iv.mean:.2f}", f"{iv.half:.2f}") == (f"{_signed(m[1]):.2f}", m[2]), r
        assert (m[3] is not None) == (label(iv, 0.0) == "not"), r
    for listed, stated, lab in (("2.13, 1.73, 1.93, 2.16, 1.51, 1.72", "1.86 ± 0.27", "not"),
                                ("1.12, 1.21, 1.31 and 1.33", "1.24 ± 0.15", "not"),
                                ("1.12, 1.21, 1.31", "1.21 ± 0.24", "reproduced")):
        iv = mean_ci([float(x) for x in listed.replace(" and", ",").split(", ")])
        assert f"{iv.mean:.2f} ± {iv.half:.2f}" == stated and stated in page and label(iv, 1.0) == lab
        assert listed in page
