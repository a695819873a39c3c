"""The `original` profile of the TWINBOT experiments (issue #16; docs/paper-twinbot.md): what it sets, that it
reaches the MACs of a run, and the CLI that selects it."""

from __future__ import annotations

import subprocess
import sys

import pytest

from uwsimnet_zenoh.experiments import table1, twinbot


def test_default_profile_changes_nothing():
    assert all(twinbot.profile_overrides(p) == {} for p in twinbot.PROTOCOLS)
    assert twinbot.receivers("support") == 2 and twinbot.receivers("buoy") == 4
    with pytest.raises(ValueError, match="profile: expected one of default, original"):
        twinbot.profile_overrides("sfama", "paper")


def test_original_profile_sets_the_originals_set_up():
    sf = twinbot.profile_overrides("sfama", "original")
    assert sf["device.*.header_bytes"] == 10 and sf["device.*.tx_fifo_bytes"] == 500
    assert (sf["flow.support.dst"], sf["flow.buoy.dst"]) == (1, 10)           # leader, explorer0
    assert (sf["device.*.mac.rtsSize"], sf["device.*.mac.ctsSize"], sf["device.*.mac.ackSize"]) == ("7", "7", "5")
    assert {k: sf[f"device.*.mac.{k}"] for k in twinbot.AQUASIM_SFAMA} == twinbot.AQUASIM_SFAMA
    al = twinbot.profile_overrides("aloha", "original")
    assert al["device.*.mac.maxRetries"] == "-1" and not any(k.endswith("overhearEndsRound") for k in al)
    no = twinbot.profile_overrides("nomac", "original")
    assert no["device.*.header_bytes"] == 5 and not any(".mac." in k for k in no)     # framing only
    assert table1.original_overrides("sfama") == sf
    assert twinbot.receivers("support", "original") == 1 and twinbot.receivers("E0", "original") == 1


def test_original_profile_reaches_the_sfama_of_a_run():
    from uwsimnet_zenoh.app.overrides import apply
    from uwsimnet_zenoh.scene.load import load_scene

    sc = apply(load_scene(twinbot.scene_path("sfama"), on_warning=lambda *_: None),
               twinbot.profile_overrides("sfama", "original"))
    for _, d in sc.devices():
        assert d.header_bytes == 10 and d.tx_fifo_bytes == 500
        assert {k: d.mac.params[k] for k in twinbot.AQUASIM_SFAMA} == twinbot.AQUASIM_SFAMA


@pytest.mark.parametrize("args, msg", [
    (["phy-layer", "--profile", "original"], "uwsimnet experiment: --profile applies to twinbot and table1"),
    (["twinbot", "--profile", "original", "--seeds", "1-2"],
     "uwsimnet experiment: twinbot --seeds runs the default profile only (table1 --profile original --seeds N"
     " gives intervals with the original's set-up)")])
def test_profile_only_where_it_applies(tmp_path, args, msg):
    r = subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", "experiment", *args, "--out", str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip() == msg


def test_cli_passes_the_profile_to_twinbot(tmp_path, monkeypatch, capsys):
    from uwsimnet_zenoh.cli import main

    seen = {}

    def fake_run(out, **kw):
        seen.update(kw)
        (out / "summary.md").write_text("# fake summary\n")

    (tmp_path / "o").mkdir()
    monkeypatch.setattr(twinbot, "run", fake_run)
    assert main(["experiment", "twinbot", "--profile", "original", "--out", str(tmp_path / "o")]) == 0
    assert seen == {"profile": "original"}
