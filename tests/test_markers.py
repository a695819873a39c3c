"""`pytest -m core` (tests/conftest.py): a test module is core when it imports only rooms below the sans-IO line,
no Zenoh, processes, sockets or threads, and no other test module."""

from __future__ import annotations

from pathlib import Path

from conftest import is_core

TESTS = Path(__file__).resolve().parent


def test_core_is_what_a_test_module_imports():
    assert is_core(str(TESTS / "test_phy.py"))               # phy, scene, engine: the core
    assert is_core(str(TESTS / "test_mac_harness.py"))
    assert is_core(__file__)                                 # conftest and the standard library
    assert not is_core(str(TESTS / "test_broker_e2e.py"))    # processes, sockets, the client library
    assert not is_core(str(TESTS / "test_output_port.py"))   # drivers/ is above the line
    assert not is_core(str(TESTS / "test_status_model.py"))  # another test module (a live broker's helpers)
