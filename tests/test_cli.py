"""The `uwsimnet` command as users run it: real processes, exit codes, one-line errors, files written."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TWO = ROOT / "scenes" / "examples" / "two-nodes.xml"


def uwsimnet(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uwsimnet_zenoh.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, timeout=120)


def bad_scene(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "bad.xml"
    p.write_text(body)
    return p


SCENE_HEAD = """<?xml version="1.0"?>
<UWSimScene>
  <CustomCommsChannel><id>0</id></CustomCommsChannel>
  <vehicle>
    <name>v</name>
    <CustomCommsDevice>
      <dccommsId>a</dccommsId><mac>1</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId>
"""


@pytest.mark.parametrize("device_extra,line,needle", [
    ("<rateErrorModel><errorUnit>bit</errorUnit><errorRateExpr>__import__('os')</errorRateExpr></rateErrorModel>",
     8, "__import__"),
    ("<bitrate>fast</bitrate>", 8, "bitrate"),
    ("<colour>red</colour>", 8, "unknown element <colour>"),
])
@pytest.mark.parametrize("cmd", ["validate", "run"])
def test_bad_scenes_give_file_line_message_exit_2_and_no_traceback(tmp_path, cmd, device_extra, line, needle):
    p = bad_scene(tmp_path, SCENE_HEAD + "      " + device_extra + "\n    </CustomCommsDevice>\n  </vehicle>\n"
                  "</UWSimScene>\n")
    r = uwsimnet(cmd, str(p))
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ": warning:" not in ln]
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"{p}:{line}: ") and needle in lines[0]
    assert "Traceback" not in r.stderr


def test_malformed_xml_and_missing_file(tmp_path):
    p = bad_scene(tmp_path, "<UWSimScene>\n  <vehicle>\n</UWSimScene>\n")
    r = uwsimnet("validate", str(p))
    assert r.returncode == 2 and r.stderr.startswith(f"{p}:3: ") and "Traceback" not in r.stderr
    r = uwsimnet("validate", str(tmp_path / "nope.xml"))
    assert r.returncode == 2 and "no such scene file" in r.stderr and "Traceback" not in r.stderr


def test_validate_ok():
    r = uwsimnet("validate", str(TWO))
    assert r.returncode == 0 and "ok (1 channels, 2 vehicles, 2 devices, 1 flows)" in r.stdout


def test_run_report_plot_round_trip(tmp_path):
    trace = tmp_path / "t.jsonl"
    r = uwsimnet("run", str(TWO), "--trace", str(trace), "--seed", "5")
    assert r.returncode == 0, r.stderr
    assert "two-nodes" in r.stdout and "60 s simulated" in r.stdout
    meta = json.loads(trace.read_text().splitlines()[0])
    assert meta["ev"] == "meta" and meta["seed"] == 5
    r = uwsimnet("report", str(trace), "--json")
    assert r.returncode == 0, r.stderr
    (flow,) = json.loads(r.stdout)["flows"].values()
    # 60 frames of 32 B, no loss, 100 m at 1500 m/s: delay 1 + 66.67 + 256 ms (docs/scene-format.md example)
    assert flow["delivered"] == 60 and flow["throughput"] == pytest.approx(32.0, rel=0.02)
    assert flow["delay_mean"] == pytest.approx(0.32367, abs=1e-4)
    r = uwsimnet("plot", str(trace), "-o", str(tmp_path / "figs"))
    assert r.returncode == 0, r.stderr
    pngs = sorted(p.name for p in (tmp_path / "figs").glob("*.png"))
    assert pngs == ["fig3-packets.png", "fig4-delay.png"]


def test_same_seed_same_bytes_through_the_command(tmp_path):
    scene = ROOT / "scenes" / "paper" / "phy-layer-rf.xml"
    outs = []
    for name, seed in (("a", "3"), ("b", "3"), ("c", "4")):
        r = uwsimnet("run", str(scene), "--trace", str(tmp_path / f"{name}.jsonl"), "--seed", seed)
        assert r.returncode == 0, r.stderr
        outs.append((tmp_path / f"{name}.jsonl").read_bytes())
    assert outs[0] == outs[1] and outs[0] != outs[2]


def test_report_on_a_malformed_trace(tmp_path):
    t = tmp_path / "bad.jsonl"
    t.write_text('{"ev": "meta", "t": 0}\n{"t": 1, "ev": "tx", \n')
    r = uwsimnet("report", str(t))
    assert r.returncode == 2 and r.stderr.startswith(f"{t}:2: ") and "Traceback" not in r.stderr


def test_user_tracing_class_sees_every_event(tmp_path):
    (tmp_path / "mytracer.py").write_text(
        "import json\n"
        "class Count:\n"
        "    def __init__(self):\n"
        "        self.n = {}\n"
        "    def on_tx(self, rec):\n"
        "        self.n['tx'] = self.n.get('tx', 0) + 1\n"
        "    def on_rx(self, rec):\n"
        "        self.n['rx'] = self.n.get('rx', 0) + 1\n"
        "        open('counts.json', 'w').write(json.dumps(self.n))\n")
    scene = TWO.read_text().replace("<UWSimScene>", "<UWSimScene>\n  <netTracingScript><className>mytracer:Count"
                                    "</className></netTracingScript>", 1)
    p = tmp_path / "traced.xml"
    p.write_text(scene)
    env_cwd = tmp_path
    r = subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, '.');"
                        "from uwsimnet_zenoh.cli import main; sys.exit(main(sys.argv[1:]))", "run", str(p)],
                       capture_output=True, text=True, cwd=env_cwd, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "counts.json").read_text()) == {"tx": 60, "rx": 60}


def test_unloadable_tracing_class_is_a_one_line_error(tmp_path):
    scene = TWO.read_text().replace("<UWSimScene>", "<UWSimScene>\n  <netTracingScript><className>nosuchmod:X"
                                    "</className></netTracingScript>", 1)
    p = tmp_path / "traced.xml"
    p.write_text(scene)
    r = uwsimnet("run", str(p))
    assert r.returncode == 2 and "nosuchmod:X" in r.stderr and "Traceback" not in r.stderr
    assert r.stderr.startswith(f"{p}:")


def test_virtual_run_loads_no_zenoh(tmp_path: Path) -> None:
    """`uwsimnet run` on the virtual clock imports neither zenoh nor the gli package (start-up time), and
    the endpoint the flags name by default is the gli client's."""
    code = ("import sys; from uwsimnet_zenoh.cli.main import main; rc = main(['run', sys.argv[1], '--trace',"
            " sys.argv[2]]); print(rc, sorted(m for m in ('zenoh', 'uwsimnet_gli', 'asyncio', 'msgpack')"
            " if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code, str(TWO), str(tmp_path / "t.jsonl")], capture_output=True,
                       text=True, cwd=ROOT, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines()[-1] == "0 []"
    from uwsimnet_gli.wire import DEFAULT_ENDPOINT

    from uwsimnet_zenoh.cli.zenoh_flags import DEFAULT_CONNECT
    assert DEFAULT_CONNECT == DEFAULT_ENDPOINT


STARTUP_PROBE = ("import sys, contextlib, io; from uwsimnet_zenoh.cli import main\n"
                 "with contextlib.redirect_stdout(io.StringIO()): rc = main(sys.argv[1:])\n"
                 "print(rc, sorted(m for m in sys.modules if m in sys.argv[0].split(',')"
                 " or m.startswith(('uwsimnet_zenoh.ros2.wire', 'uwsimnet_zenoh.ros2.bridge', 'uwsimnet_zenoh.bus.',"
                 " 'uwsimnet_zenoh.view.', 'uwsimnet_zenoh.drivers', 'uwsimnet_zenoh.bridges', 'zenoh', 'rich'))))")


def _imported(argv: list[str], also: tuple[str, ...]) -> str:
    code = STARTUP_PROBE.replace("sys.argv[0]", repr(",".join(also)))
    p = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert p.returncode == 0, p.stderr
    return p.stdout.splitlines()[-1]


@pytest.mark.parametrize("trace", [False, True])
def test_virtual_run_imports_only_what_it_uses(tmp_path: Path, trace: bool) -> None:
    """Start-up time (issue #19): a virtual run of a NOMAC, non-acoustic scene imports no ROS 2 wire, Zenoh edge,
    page, driver or pcap module, nor the MACs and the acoustic physics it does not use."""
    argv = ["run", str(TWO)] + (["--trace", str(tmp_path / "t.jsonl")] if trace else [])
    unused = ("uwsimnet_zenoh.analysis.pcap", "uwsimnet_zenoh.analysis.figures", "uwsimnet_zenoh.app.realtime",
              "uwsimnet_zenoh.mac.aloha", "uwsimnet_zenoh.mac.sfama", "uwsimnet_zenoh.phy.acoustic", "matplotlib")
    assert _imported(argv, unused) == "0 []"


def test_report_imports_no_scene_nor_engine(tmp_path: Path) -> None:
    t = tmp_path / "t.jsonl"
    assert uwsimnet("run", str(TWO), "--trace", str(t)).returncode == 0
    assert _imported(["report", str(t)], ("pydantic", "lxml", "uwsimnet_zenoh.engine", "uwsimnet_zenoh.scene")) \
        == "0 []"


def test_run_parser_alone_parses_as_the_whole() -> None:
    from uwsimnet_zenoh.cli.main import build_parser

    argv = ["run", "x.xml", "--trace", "t.jsonl", "--seed", "3", "--connect", "tcp/h:1"]
    assert vars(build_parser("run").parse_args(argv)) == vars(build_parser().parse_args(argv))


def test_the_console_script_freezes_what_the_command_made_and_keeps_its_exit_code(monkeypatch):
    """`uwsimnet` is `cli.command`: main's exit code, then gc.freeze() (the process's exit would otherwise
    collect and free every object of a run one by one)."""
    import gc
    import tomllib

    import uwsimnet_zenoh.cli as cli

    scripts = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["uwsimnet"] == "uwsimnet_zenoh.cli:command"
    made = []

    def fake_main():
        a: list = []
        a.append(a)             # a reference cycle the command leaves behind
        made.append(a)
        return 3

    monkeypatch.setattr(cli, "main", fake_main)
    before = gc.get_freeze_count()
    try:
        assert cli.command() == 3
        assert gc.get_freeze_count() > before
    finally:
        gc.unfreeze()           # this test process goes on
