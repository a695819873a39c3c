"""Validation that matches what runs (#21): `uwsimnet validate` refuses, in one line with file:line and exit
code 2, what a run would trip over or never finish; runtime `add_device` goes through the same models;
and a bounded fuzz over scene mutations never gets a traceback out of `validate`."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from uwsimnet_zenoh.cli.main import main
from uwsimnet_zenoh.scene.load import MAX_SCENE_BYTES
from uwsimnet_zenoh.scene.model import Device
from uwsimnet_zenoh.scene.native import MAX_FLOW_FRAMES, MAX_FLOW_RATE, MIN_FLOW_INTERVAL

ROOT = Path(__file__).resolve().parents[1]
TWO = (ROOT / "scenes" / "examples" / "two-nodes.xml").read_text()


def validate(tmp_path: Path, text: str, capsys) -> tuple[int, str]:
    p = tmp_path / "s.xml"
    p.write_text(text)
    capsys.readouterr()
    rc = main(["validate", str(p)])
    err = capsys.readouterr().err
    return rc, "\n".join(line for line in err.splitlines() if ": warning: " not in line)


def line_of(text: str, needle: str) -> int:
    return text[:text.index(needle)].count("\n") + 1


@pytest.mark.parametrize("old, new, needle, message", [
    ("<dst>2</dst>", "<dst>1</dst>", "<dst>1</dst>",
     "dst: 1 is the address of the flow's own device 'alpha-modem'"),
    ("<interval>1</interval>", "<interval>1e-9</interval>", "<interval>1e-9",
     f"interval 1e-09 s is below the bound of {MIN_FLOW_INTERVAL:g} s"),
    ("<interval>1</interval>", "<rate>1000000</rate>", "<rate>", f"above the bound of {MAX_FLOW_RATE:g}/s"),
    ("<duration>60</duration>", "<duration>1e9</duration>", None, None),       # stop 60: fine
    ("<stop>60</stop>", "", None, None),                                    # 60 frames: fine
    ("<interval>1</interval>", "<interval>0.0001</interval>", "<interval>0.0001",
     f"above the bound of {MAX_FLOW_FRAMES:g}"),
])
def test_flows_a_run_cannot_finish_or_that_go_to_self(tmp_path, capsys, old, new, needle, message):
    text = TWO.replace(old, new, 1)
    if old == "<interval>1</interval>" and "0.0001" in new:
        text = text.replace("<stop>60</stop>", "").replace("<duration>60</duration>", "<duration>2e6</duration>")
    rc, err = validate(tmp_path, text, capsys)
    if message is None:
        assert rc == 0, err
        return
    assert rc == 2
    assert err.count("\n") == 0 and message in err
    assert err.startswith(f"{tmp_path / 's.xml'}:{line_of(text, needle)}: ")


@pytest.mark.parametrize("mac, message", [
    ("<macProtocol><name>aloha</name><maxBackof>3</maxBackof></macProtocol>",
     "macProtocol aloha: unknown parameter(s) maxBackof (it reads: "),
    ("<macProtocol><name>no_such_module:Mac</name></macProtocol>", "cannot load MAC protocol"),
    ("<macProtocol><name>uwsimnet_zenoh.trace.events:Tracer</name></macProtocol>", "is not a subclass"),
    ("<macProtocol><name>aloha</name><maxBackoff>x</maxBackoff></macProtocol>", "maxBackoff"),
])
def test_mac_problems_are_found_at_validate_with_the_line(tmp_path, capsys, mac, message):
    text = TWO.replace("<mac>2</mac>", "<mac>2</mac>\n      " + mac, 1)
    rc, err = validate(tmp_path, text, capsys)
    assert rc == 2 and err.count("\n") == 0, err
    assert message in err
    assert err.startswith(f"{tmp_path / 's.xml'}:{line_of(text, '<macProtocol>')}: ")   # the loader or the build


def test_a_scene_over_the_size_limit_is_refused_before_parsing(tmp_path, capsys):
    text = TWO.replace("</UWSimScene>", "<!--" + "x" * MAX_SCENE_BYTES + "--></UWSimScene>")
    rc, err = validate(tmp_path, text, capsys)
    assert rc == 2 and err.count("\n") == 0
    assert f"larger than the limit of {MAX_SCENE_BYTES} bytes" in err


def test_runtime_devices_are_checked_by_the_scene_model():
    base = {"dccomms_id": "n", "address": 7, "tx_channel": 0, "rx_channel": 0}
    Device.model_validate(base)
    for bad in ({"bitrate": math.inf}, {"bitrate": math.nan}, {"max_distance": math.inf},
                {"min_distance": 10.0, "max_distance": 5.0}, {"address": 255}, {"intrinsic_tx_s": -1}):
        with pytest.raises(ValidationError):
            Device.model_validate({**base, **bad})


# -- fuzz: mutated scenes give ok or one line, exit 2, never a traceback ----------------------------------
_VALUE = re.compile(r">([^<>\n]+)</")
_SPOTS = [m.span(1) for m in _VALUE.finditer(TWO)]
_NASTY = st.sampled_from(["nan", "inf", "-inf", "-1", "0", "1e308", "1e-320", "", " ", "1e9", "99999999999999999999",
                          "x", "2", "255", "65536", "0x10", "1_000", "aloha", "a:b", "os:system", "poisson", "3.5"])


@settings(max_examples=150)
@given(st.lists(st.tuples(st.integers(0, len(_SPOTS) - 1), st.one_of(_NASTY, st.text(max_size=8))),
                min_size=1, max_size=4))
def test_fuzzed_scenes_validate_to_ok_or_one_line(tmp_path_factory, edits):
    text = TWO
    for i, value in sorted(dict(edits).items(), reverse=True):     # from the end: spans stay valid
        a, b = _SPOTS[i]
        value = value.replace("<", "").replace("&", "")
        text = text[:a] + value + text[b:]
    p = tmp_path_factory.mktemp("fuzz") / "s.xml"
    p.write_text(text)
    import contextlib
    import io
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["validate", str(p)])
    lines = [line for line in err.getvalue().splitlines() if ": warning: " not in line]
    assert rc in (0, 2)
    if rc == 2:
        assert len(lines) == 1 and lines[0].startswith(f"{p}:"), lines
    else:
        assert lines == []
