"""The grid cache of the channel model "bellhop": a grid is named by its content and by the Bellhop build that
made it (`program_tag`: the SHA-256 of the program's bytes), so a new Bellhop computes its own grids while a
machine without Bellhop still uses any cached one.  The real program (`make bellhop`) is needed for the first
half; it skips with the reason when absent."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from uwsimnet_zenoh.engine.network import Network
from uwsimnet_zenoh.phy import bellhop
from uwsimnet_zenoh.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"
SHIPPED = next((DATA / "bellhop").glob("*.npz"))
STEM = SHIPPED.name.split("-")[0]


def _model():
    return Network(load_scene(DATA / "ocean-shadow.xml")).modems["buoy-modem"].error


def test_the_tag_is_the_programs_sha256(tmp_path):
    exe = tmp_path / "bellhop"
    exe.write_bytes(b"#!/bin/sh\nexit 1\n" * 100_000)            # over the reader's 1 MiB chunks
    assert bellhop.program_tag(str(exe)) == hashlib.sha256(exe.read_bytes()).hexdigest()[:12]


def test_without_bellhop_a_grid_of_any_build_serves(tmp_path, monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(tmp_path))
    monkeypatch.setenv("UWSIMNET_BELLHOP", "/nonexistent/bellhop")
    (tmp_path / "bellhop").mkdir()
    other = tmp_path / "bellhop" / f"{STEM}-000000000000.npz"
    shutil.copy(SHIPPED, other)
    assert _model().path == other
    other.rename(tmp_path / "bellhop" / f"{STEM}.npz")          # a grid cached before the tags
    assert _model().path == tmp_path / "bellhop" / f"{STEM}.npz"


@pytest.mark.skipif(bellhop.find_program() is None, reason="Bellhop is not installed (`make bellhop`)")
def test_with_bellhop_a_grid_of_another_build_is_computed_again(tmp_path, monkeypatch):
    monkeypatch.setenv("UWSIMNET_CACHE", str(tmp_path))
    program = bellhop.find_program()
    assert program is not None
    (tmp_path / "bellhop").mkdir()
    shutil.copy(SHIPPED, tmp_path / "bellhop" / f"{STEM}-000000000000.npz")
    model = _model()
    assert model.path == tmp_path / "bellhop" / f"{STEM}-{bellhop.program_tag(program)}.npz"
    assert model.path.exists()
    again = _model()                                          # now cached under this build's name
    assert again.path == model.path and (again.grid.tl == model.grid.tl).all()
    if SHIPPED.stem.endswith(bellhop.program_tag(program)):  # the shipped grid's build: it is reproduced exactly
        shipped = bellhop.Grid.load(SHIPPED)
        for name in ("tl", "delay", "spread", "late"):
            assert np.array_equal(getattr(model.grid, name), getattr(shipped, name), equal_nan=True), name
