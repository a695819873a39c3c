"""`uwsimnet bridge socket` and `uwsimnet bridge mq` on a running broker: the C client (built with cc) and a
dccomms-style POSIX-queue client exchange frames with a Python uwsimnet_gli client through the simulator;
broker and bridges are separate processes, over real Zenoh."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("uwsimnet_gli")
from test_broker_e2e import UWSIMNET, Broker, Proc, device_xml, scene_xml, stop_all, vehicle_xml  # noqa: E402
from uwsimnet_gli import World  # noqa: E402

from uwsimnet_zenoh.bridges import posix_mq  # noqa: E402
from uwsimnet_zenoh.bridges.mq_bridge import GliQueueClient  # noqa: E402
from uwsimnet_zenoh.formats import dccomms as fr  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WORLD = "hilbridge"
WAIT = 10.0


@pytest.fixture(scope="module")
def c_client(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler (cc) on this machine")
    exe = tmp_path_factory.mktemp("c") / "gli_socket_client"
    subprocess.run([cc, "-std=c99", "-Wall", "-O2", "-o", str(exe), str(ROOT / "gli_clients/c/gli_socket_client.c")],
                   check=True, timeout=60)
    return exe


@pytest.mark.skipif(not posix_mq.available(), reason="POSIX message queues need Linux librt")
def test_c_client_and_mq_client_through_the_simulator(tmp_path: Path, c_client):
    scene = tmp_path / "bridges.xml"
    scene.write_text(scene_xml(world=WORLD, vehicles="".join([
        vehicle_xml("a", (0, 0, 0), device_xml("a-m", 1)),
        vehicle_xml("b", (50, 0, 0), device_xml("b-m", 2)),
        vehicle_xml("c", (100, 0, 0), device_xml("c-m", 3)),
    ])))
    cid = f"uwsimtest{os.getpid()}c"
    started: list[Proc] = []
    proc = None
    try:
        broker = Broker(scene, tmp_path / "trace.jsonl")
        started.append(broker)
        sock = Proc([*UWSIMNET, "bridge", "socket", "--id", "a-m", "--world", WORLD, "--connect", broker.endpoint])
        started.append(sock)
        line = sock.expect("uwsimnet: bridge socket ready", 20)
        port = int(line.split("tcp 127.0.0.1:")[1].split()[0])
        mq = Proc([*UWSIMNET, "bridge", "mq", "--id", "c-m", "--dccomms-id", cid, "--connect", broker.endpoint])
        started.append(mq)
        mq.expect("uwsimnet: bridge mq ready", 20)

        with World(WORLD, connect=broker.endpoint) as w, GliQueueClient(cid, address=3) as app:
            assert app.wait_ready(WAIT)
            py = w.modem("b-m")
            # the C program sends 3 frames to b-m (2), then waits for 2 frames
            proc = subprocess.Popen([str(c_client), "127.0.0.1", str(port), "2", "3", "2", "10", "hi from C"],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            got = [py.receive(timeout=WAIT) for _ in range(3)]
            assert [(f.src, f.dst, f.data) for f in got if f] == [(1, 2, f"hi from C #{i}".encode())
                                                                  for i in (1, 2, 3)]
            py.send(1, b"hello C \x00\xff")
            py.send(1, b"second")
            out, err = proc.communicate(timeout=WAIT + 5)
            assert proc.returncode == 0, (out, err)
            lines = out.splitlines()
            assert lines[0] == "HELLO address=1 max_payload=2048 id=a-m"
            rx = [x for x in lines if x.startswith("RX ")]
            assert len(rx) == 2 and rx[0].startswith("RX src=2 dst=1 ")
            for tag in (1, 2, 3):       # delivery learnt from the broker's trace, over Zenoh
                assert any(f"tag={tag} event=delivered" in x for x in lines), lines

            # the dccomms application (c-m, 3) and the Python client (b-m, 2)
            app.send(2, b"from dccomms", seq=4_000_000_042)
            f = py.receive(timeout=WAIT)
            assert f is not None and (f.src, f.dst, f.data) == (3, 2, b"from dccomms")
            assert f.msg == {"aseq": 4_000_000_042}         # the app's own seq (SetVirtualSeq), through the broker
            py.send(3, b"to dccomms")
            # no MAC: the app also got the C program's frames for b-m (implicit broadcast); it filters, as
            # a dccomms application does
            heard = []
            while (g := app.receive(WAIT)) is not None and g.dst != 3:
                heard.append((g.src, g.dst, g.payload))
            assert g is not None and (g.src, g.dst, g.payload) == (2, 3, b"to dccomms")
            assert [(1, 2, f"hi from C #{i}".encode()) for i in (1, 2, 3)] == [h for h in heard if h[0] == 1]
            assert (2, 1, b"second") in heard
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(5)
        errors = stop_all(started)
        for q in (fr.tx_queue_name(cid), fr.rx_queue_name(cid)):
            with contextlib.suppress(Exception):
                posix_mq.MessageQueue.unlink(q)
        assert not errors, errors
