"""Bad input on the command line and in traces given to `report`/`plot`: one line on stderr, exit 2,
never a traceback (issue #21); options that do not apply are refused; no NaN/Infinity in JSON we write."""

from __future__ import annotations

import gzip
import io
import json
import math
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from uwsimnet_zenoh.analysis import TraceError, read_trace
from uwsimnet_zenoh.cli.main import main
from uwsimnet_zenoh.trace.events import JsonlSink, finite

ROOT = Path(__file__).resolve().parents[1]
SCENE = """<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><duration>10</duration></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  <vehicle><name>a</name><position>0 0 0</position><CustomCommsDevice><dccommsId>a-m</dccommsId><mac>1</mac>
    <txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>1000</bitrate>
    <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>
  </CustomCommsDevice></vehicle>
  <vehicle><name>b</name><position>{x} 0 0</position><CustomCommsDevice><dccommsId>b-m</dccommsId><mac>2</mac>
    <txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>1000</bitrate>
    <rateErrorModel><errorUnit>packet</errorUnit><errorRateExpr>0</errorRateExpr></rateErrorModel>
  </CustomCommsDevice></vehicle>
  {flows}
</UWSimScene>"""
FLOW = "<flow><name>ab</name><src>a-m</src><dst>2</dst><size>10</size><interval>1</interval></flow>"


def scene(tmp: Path, x: str = "100", flows: str = "") -> str:
    p = tmp / "s.xml"
    p.write_text(SCENE.format(x=x, flows=flows))
    return str(p)


def run_cli(argv: list[str], capsys) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def one_line_exit_2(rc: int, err: str) -> None:
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip() and "warning:" not in ln]
    assert len(lines) == 1 and "Traceback" not in err, err


# -- numbers and options ------------------------------------------------------------------------
@pytest.mark.parametrize("opt,value,msg", [
    ("--duration", "-5", "--duration -5: must be a number of seconds > 0"),
    ("--duration", "-1", "--duration -1: must be"),
    ("--duration", "0", "--duration 0: must be"),
    ("--duration", "nan", "--duration nan: must be"),
    ("--duration", "inf", "--duration inf: must be"),
    ("--duration", "1e300", "--duration 1e+300: must be"),
    ("--speed", "1e-300", "--speed 1e-300: must be a number from 0.001 to 10000"),
    ("--speed", "inf", "--speed inf: must be"),
    ("--speed", "nan", "--speed nan: must be"),
    ("--speed", "-2", "--speed -2: must be")])
@pytest.mark.parametrize("clock", ["virtual", "realtime"])
def test_numbers_are_range_checked_in_one_line(tmp_path, capsys, opt, value, msg, clock):
    rc, _, err = run_cli(["run", scene(tmp_path), "--clock", clock, opt, value], capsys)
    one_line_exit_2(rc, err)
    assert err.startswith(msg), err


@pytest.mark.parametrize("opts,named", [
    (["--connect", "tcp/127.0.0.1:1"], "--connect: applies"),
    (["--channels", "0"], "--channels: applies"),
    (["--listen", "tcp/127.0.0.1:1", "--speed", "2"], "--listen, --speed: apply"),
    (["--zenoh-config", "x.json5"], "--zenoh-config: applies"),
    (["--world", "w"], "--world: applies")])
def test_realtime_options_on_a_virtual_run_are_refused(tmp_path, capsys, opts, named):
    rc, out, err = run_cli(["run", scene(tmp_path), *opts], capsys)
    one_line_exit_2(rc, err)
    assert err.startswith(named) and "runs on the virtual clock (add --clock realtime)" in err, err
    assert out == ""                                      # nothing was run


@pytest.mark.parametrize("argv", [["run", "s.xml", "--duration", "-1e3"], ["run", "s.xml", "--duration", "x"],
                                  ["run"], ["report"], ["nosuch"], ["run", "s.xml", "--clock", "fast"]])
def test_argument_errors_are_one_line(capsys, argv):
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(argv)
    one_line_exit_2(e.value.code, capsys.readouterr().err)


def test_a_valid_virtual_run_still_runs(tmp_path, capsys):
    rc, out, err = run_cli(["run", scene(tmp_path, flows=FLOW), "--duration", "5"], capsys)
    assert rc == 0, err
    assert "5 s simulated" in out


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(d=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)),
       s=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)),
       clock=st.sampled_from([None, "virtual"]))
def test_fuzz_run_numbers_never_traceback(tmp_path, capsys, d, s, clock):
    argv = ["run", scene(tmp_path)]                  # no flows: a valid duration runs in no events
    if clock:
        argv += ["--clock", clock]
    if d is not None:
        argv += [f"--duration={d!r}"]             # (a separate "-1e+16" would read as an option)
    if s is not None:
        argv += [f"--speed={s!r}"]
    rc, _, err = run_cli(argv, capsys)
    if rc != 0:
        one_line_exit_2(rc, err)
    else:
        assert s is None and (d is None or 0 < d <= 1e9), (d, s)


# -- no NaN / Infinity in JSON we write ---------------------------------------------------------
def test_a_trace_of_astronomical_distances_is_strict_json(tmp_path, capsys):
    """Vehicles 1e200 m apart: the distance overflows; the trace says null, never Infinity/NaN."""
    trace = tmp_path / "t.jsonl"
    rc, _, err = run_cli(["run", scene(tmp_path, x="1e200", flows=FLOW), "--trace", str(trace),
                          "--duration", "3"], capsys)
    assert rc == 0, err
    text = trace.read_text()
    for bad in ("NaN", "Infinity"):
        assert bad not in text
    recs = [json.loads(line, parse_constant=lambda c: pytest.fail(c)) for line in text.splitlines()]
    assert any("dist" in r for r in recs)
    assert all(r.get("dist") is None or math.isfinite(r["dist"]) for r in recs)
    rc, out, err = run_cli(["report", str(trace), "--json"], capsys)
    assert rc == 0, err
    json.loads(out, parse_constant=lambda c: pytest.fail(c))


def test_jsonl_sink_writes_null_for_non_finite_numbers():
    fh = io.StringIO()
    sink = JsonlSink(fh)
    sink({"t": 1.0, "x": math.inf, "y": [math.nan, 1.5], "z": {"w": -math.inf}})
    sink.header({"ev": "meta", "duration": math.inf})
    assert fh.getvalue() == '{"t":1.0,"x":null,"y":[null,1.5],"z":{"w":null}}\n{"ev":"meta","duration":null}\n'
    assert finite((1.0, math.nan)) == [1.0, None]


# -- traces given to report / plot --------------------------------------------------------------
@pytest.fixture(scope="module")
def good_trace(tmp_path_factory) -> list[str]:
    d = tmp_path_factory.mktemp("good")
    p = d / "s.xml"
    p.write_text(SCENE.format(x="100", flows=FLOW))
    trace = d / "t.jsonl"
    assert main(["run", str(p), "--trace", str(trace), "--duration", "4"]) == 0
    return trace.read_text().splitlines()


def bad_traces(lines: list[str]) -> dict[str, bytes]:
    meta = json.loads(lines[0])
    text = "\n".join(lines) + "\n"
    gz = gzip.compress(text.encode())
    rec = json.loads(lines[2])

    def with_meta(**kw) -> bytes:
        return (json.dumps({**meta, **kw}) + "\n" + "\n".join(lines[1:]) + "\n").encode()

    def with_rec(**kw) -> bytes:
        return (lines[0] + "\n" + json.dumps({**rec, **kw}) + "\n").encode()
    return {
        "truncated.jsonl.gz": gz[: len(gz) // 2],
        "garbage.jsonl.gz": b"\x1f\x8b\x08\x00garbage" * 10,
        "nested.jsonl": (lines[0] + "\n" + "[" * 100_000 + "]" * 100_000 + "\n").encode(),
        "nested-field.jsonl": (lines[0] + "\n" + json.dumps(rec)[:-1] + ',"x":' + "[" * 5000 + "]" * 5000
                               + "}\n").encode(),
        "hugeint-digits.jsonl": (lines[0] + "\n" + json.dumps(rec).replace(f'"seq": {rec["seq"]}',
                                 '"seq": 1' + "0" * 5000) + "\n").encode(),
        "hugeint-t.jsonl": with_rec(t=10 ** 400),
        "hugeint-seq.jsonl": with_rec(seq=2 ** 64),
        "nan-t.jsonl": (lines[0] + "\n" + json.dumps(rec).replace(f'"t": {json.dumps(rec["t"])}', '"t": NaN')
                        + "\n").encode(),
        "meta-duration-str.jsonl": with_meta(duration="long"),
        "meta-duration-huge.jsonl": with_meta(duration=10 ** 400),
        "meta-flows-list.jsonl": with_meta(flows=[1, 2]),
        "meta-flow-size.jsonl": with_meta(flows={"ab": {**meta["flows"]["ab"], "size": "ten"}}),
        "meta-device-str.jsonl": with_meta(devices={"a-m": "x"}),
        "meta-device-bitrate.jsonl": with_meta(devices={"a-m": {"address": 1, "bitrate": [1]}}),
        "not-utf8.jsonl": b"\xff\xfe" + text.encode(),
    }


def test_bad_traces_fail_report_and_plot_in_one_line(tmp_path, capsys, good_trace):
    assert len(good_trace) > 5
    for name, data in bad_traces(good_trace).items():
        p = tmp_path / name
        p.write_bytes(data)
        for argv in (["report", str(p)], ["report", str(p), "--json"], ["plot", str(p), "-o", str(tmp_path / "f")]):
            rc, _, err = run_cli(argv, capsys)
            one_line_exit_2(rc, err)
            assert err.startswith(str(p)), (name, err)
        with pytest.raises(TraceError):
            meta, events = read_trace(p)
            list(events)


def test_report_depth_limit_leaves_recursion_alone(tmp_path, capsys, good_trace):
    """The nesting bound is checked before json.loads: the interpreter's recursion limit is untouched."""
    p = tmp_path / "n.jsonl"
    p.write_bytes(bad_traces(good_trace)["nested.jsonl"])
    limit = sys.getrecursionlimit()
    rc, _, err = run_cli(["report", str(p)], capsys)
    assert rc == 2 and "nested deeper than 32 levels" in err and sys.getrecursionlimit() == limit


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=4), c, max_size=3),
                    max_leaves=8)
FIELDS = ["t", "ev", "ch", "dev", "src", "dst", "seq", "size", "flow", "kind", "reason", "dist", "fifo",
          "duration", "flows", "devices", "version", "seed"]


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_report_on_mutated_traces_never_tracebacks(tmp_path, capsys, good_trace, data):
    lines = list(good_trace)
    how = data.draw(st.sampled_from(["field", "drop-field", "cut", "bytes", "gzip-cut"]))
    i = data.draw(st.integers(0, len(lines) - 1))
    rec = json.loads(lines[i])
    if how == "field":
        rec[data.draw(st.sampled_from(FIELDS))] = data.draw(JSON)
        lines[i] = json.dumps(rec)
    elif how == "drop-field":
        rec.pop(data.draw(st.sampled_from(sorted(rec))), None)
        lines[i] = json.dumps(rec)
    elif how == "cut":
        lines[i] = lines[i][: data.draw(st.integers(0, len(lines[i])))]
    raw = ("\n".join(lines) + "\n").encode()
    name = "t.jsonl"
    if how == "bytes":
        k = data.draw(st.integers(0, len(raw) - 1))
        raw = raw[:k] + data.draw(st.binary(min_size=1, max_size=4)) + raw[k + 1:]
    elif how == "gzip-cut":
        z = gzip.compress(raw)
        raw, name = z[: data.draw(st.integers(0, len(z)))], "t.jsonl.gz"
    p = tmp_path / name
    p.write_bytes(raw)
    for argv in (["report", str(p)], ["report", str(p), "--json"]):
        rc, out, err = run_cli(argv, capsys)
        if rc == 0:
            if "--json" in argv:
                json.loads(out, parse_constant=lambda c: pytest.fail(f"{c} in report --json"))
        else:
            one_line_exit_2(rc, err)


def test_report_on_a_meta_whose_device_has_no_integer_address(tmp_path, capsys, good_trace):
    """Found by the fuzz above (byte 195 of the meta made a space): an address that is not an integer matched no
    frame in pure Python and broke the compiled fold's typed table; now it matches none in both."""
    meta = json.loads(good_trace[0])
    meta["devices"]["b-m"]["address"] = None
    p = tmp_path / "t.jsonl"
    p.write_text("\n".join([json.dumps(meta), *good_trace[1:]]) + "\n")
    rc, out, err = run_cli(["report", str(p)], capsys)
    assert "Traceback" not in err
    if rc != 0:
        one_line_exit_2(rc, err)
