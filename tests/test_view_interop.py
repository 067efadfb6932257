"""The live view read by the Foxglove ecosystem's own client: npm's ``@foxglove/ws-protocol`` under node (the
library Lichtblick is built on), speaking ``foxglove.websocket.v1`` and decoding every message from the
schema the server advertises. Installed from npm by the test itself (tests/node/package.json); skipped,
saying so, only where node or npm is missing."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import queue
import shutil
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from acquisition.messages import Event, MapTile, PointCloudMessage, PoseBatch
from acquisition.processes import free_port
from acquisition.workers.view import ViewWorker, ViewWorkerConfig
from acquisition.workers.view_protocols import answer_for_client, offered_subprotocols, request_for_sdk

NODE_DIR = Path(__file__).resolve().parent / "node"
HEAD = (b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
        b"Sec-WebSocket-Protocol: %s\r\n\r\n")


@pytest.mark.parametrize("offered, forwarded, renamed", [
    (b"foxglove.websocket.v1", ["foxglove.sdk.v1"], True),
    (b"foxglove.sdk.v1, foxglove.websocket.v1", ["foxglove.sdk.v1", "foxglove.websocket.v1"], False),
    (b"foxglove.sdk.v1.1", ["foxglove.sdk.v1.1"], False),
    (b"mqtt", ["mqtt"], False),
])
def test_the_bridge_renames_only_a_client_that_speaks_foxglove_websocket_v1_alone(offered, forwarded, renamed):
    head, rename = request_for_sdk(HEAD % offered)
    assert offered_subprotocols(head) == forwarded and rename is renamed
    assert head.endswith(b"\r\n\r\n") and b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==" in head
    answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n"
    assert answer_for_client(answer) == answer.replace(b"foxglove.sdk.v1", b"foxglove.websocket.v1")


@pytest.mark.parametrize("subprotocol", ["foxglove.websocket.v1", "foxglove.sdk.v1"])
def test_a_client_offering_either_subprotocol_alone_is_served(subprotocol):
    """Without the bridge the SDK's server answers HTTP 400 to foxglove.websocket.v1."""
    import websockets

    port = free_port()
    worker = ViewWorker(ViewWorkerConfig("127.0.0.1", port, "tcp://unused:1", "tcp://unused:2", "tcp://unused:3"), None)
    worker.warm_up()

    async def connect():
        async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[subprotocol]) as ws:
            first = json.loads(await asyncio.wait_for(ws.recv(), 5))
            return ws.subprotocol, first

    try:
        chosen, first = asyncio.run(connect())
    finally:
        worker.write_products()
    assert chosen == subprotocol
    assert first["op"] == "serverInfo" and first["name"] == "sarbot"


@pytest.fixture(scope="module")
def node_client() -> list[str]:
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node and npm are not installed: the @foxglove/ws-protocol interop test needs them "
                    "(apt-get install nodejs npm)")
    if not (NODE_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        res = subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--prefix", str(NODE_DIR)], capture_output=True,
                             text=True, timeout=600)
        assert res.returncode == 0, f"npm ci in {NODE_DIR} failed:\n{res.stderr[-2000:]}"
    return [node, str(NODE_DIR / "foxglove_client.mjs")]


class _Lines(queue.Queue):
    """The client's stdout, line by line, read by a thread of its own. ``rest`` waits for the end of the
    output: when the client has exited, its last lines may still be in the pipe, not yet in the queue (on a
    loaded CI machine the one line that ends the client, the one the test wants, was read too late)."""

    def __init__(self, proc: subprocess.Popen):
        super().__init__()
        self.reader = threading.Thread(target=lambda: [self.put(line) for line in proc.stdout], daemon=True)
        self.reader.start()

    def rest(self, timeout_s: float = 10.0) -> list[str]:
        self.reader.join(timeout_s)
        out = []
        while not self.empty():
            out.append(self.get())
        return out


def _lines(proc: subprocess.Popen) -> _Lines:
    return _Lines(proc)


def test_the_official_foxglove_ws_protocol_client_decodes_map_pose_points_and_events(node_client):
    port = free_port()
    mounts = {"left_front": ([0.15, 0.2, 0.3], [0.0, 0.0, 0.7071068, 0.7071068])}
    worker = ViewWorker(ViewWorkerConfig("127.0.0.1", port, "tcp://unused:1", "tcp://unused:2", "tcp://unused:3",
                                         mounts=mounts), None)
    worker.warm_up()
    wanted = ["/map", "/pose", "/tf", "/radar/left_front/points", "/events"]
    proc = subprocess.Popen([*node_client, f"ws://127.0.0.1:{port}", "foxglove.websocket.v1", "20", *wanted],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = _lines(proc)
    got: list[dict] = []
    try:
        deadline = time.monotonic() + 20
        while not any(d.get("event") == "advertise" and d["topic"] == "/map" for d in got):
            got.append(json.loads(lines.get(timeout=max(0.1, deadline - time.monotonic()))))
        time.sleep(0.3)  # the client's subscriptions reach the server
        rng = np.random.default_rng(1)
        tile = (rng.normal(size=(16, 16)) + 1j * rng.normal(size=(16, 16))).astype(np.complex64)
        xyz, doppler = rng.normal(size=(3, 3)).astype(np.float32), rng.normal(size=3).astype(np.float32)
        worker.handle(MapTile((4, 7), 0.01, 16, tile), live=True)
        worker.handle(PoseBatch(np.array([9_000_000_001], np.int64), np.array([[1.5, -2.0, 0.0]]),
                                np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3))), live=True)
        worker.handle(PointCloudMessage("left_front", 9_000_000_000, xyz, doppler), live=True)
        worker.handle(Event(9_000_000_002, "radar.left_front", "error", "process exited with code -9; restarting"),
                      live=True)
        worker.step()
        proc.wait(timeout=25)
        got.extend(json.loads(line) for line in lines.rest())
    finally:
        proc.kill()
        worker.write_products()
    assert proc.returncode == 0, proc.stderr.read()[-2000:]
    assert got[0] == {"event": "open", "protocol": "foxglove.websocket.v1"}
    messages = {d["topic"]: d for d in got if "message" in d}
    assert sorted(messages) == sorted(wanted)

    grid = messages["/map"]
    assert grid["schemaName"] == "foxglove.Grid" and grid["encoding"] == "protobuf"
    g = grid["message"]
    assert g["frame_id"] == "world" and g["column_count"] == 16 and g["fields"][0]["name"] == "db"
    assert g["cell_size"] == {"x": pytest.approx(0.01), "y": pytest.approx(0.01)}
    assert g["pose"]["position"]["x"] == pytest.approx(4 * 16 * 0.01) and g["pose"]["position"]["y"] == pytest.approx(7 * 16 * 0.01)
    db = np.frombuffer(base64.b64decode(g["data"]), "<f4").reshape(16, 16)
    np.testing.assert_allclose(db, 20 * np.log10(np.abs(tile) / np.abs(tile).max()), atol=1e-4)

    pose = messages["/pose"]["message"]
    assert pose["pose"]["position"] == {"x": 1.5, "y": -2.0, "z": 0.0}
    assert pose["timestamp"] == {"seconds": 9, "nanos": 1}  # google.protobuf.Timestamp
    frames = {(t["parent_frame_id"], t["child_frame_id"]) for t in messages["/tf"]["message"]["transforms"]}
    assert frames == {("world", "base_link"), ("base_link", "left_front")}
    cloud = messages["/radar/left_front/points"]["message"]
    assert cloud["frame_id"] == "left_front" and [f["name"] for f in cloud["fields"]] == ["x", "y", "z", "doppler"]
    np.testing.assert_array_equal(np.frombuffer(base64.b64decode(cloud["data"]), "<f4").reshape(3, 4),
                                  np.column_stack([xyz, doppler]))
    log_message = messages["/events"]["message"]
    assert messages["/events"]["schemaName"] == "foxglove.Log"
    assert log_message["message"] == "process exited with code -9; restarting" and log_message["name"] == "radar.left_front"
    assert log_message["level"] in (4, "ERROR")  # foxglove.Log.Level.ERROR
    assert worker.bridge.renamed == 1


def _descendant_named(comm: str) -> int | None:
    """The pid of a process below this one whose name (``/proc/PID/comm``) is ``comm``."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        name = text[text.index("(") + 1:text.rindex(")")]
        parents[int(stat.parent.name)] = (int(text[text.rindex(")") + 2:].split()[1]), name)
    for pid, (_, name) in parents.items():
        if name != comm:
            continue
        ancestor = pid
        while ancestor in parents and ancestor != os.getpid():
            ancestor = parents[ancestor][0]
        if ancestor == os.getpid():
            return pid
    return None


def test_a_killed_driver_reaches_the_official_client_as_an_event_and_the_file_alike(node_client, tmp_path):
    """The daemon writes a restart to /events and publishes it again for viewers: the live view's /events
    (foxglove.Log) shows what the file holds."""
    from acquisition.daemon import Setup, record
    from acquisition.processes import free_tcp_endpoint
    from acquisition.workers import WorkerSpec
    from drivers.radar.link import RadarLink
    from imaging.core.rig import default_rig
    from imaging.io.recording import Recording

    view_port = free_port()
    health = free_tcp_endpoint()
    view = WorkerSpec("view", ViewWorker, ViewWorkerConfig("127.0.0.1", view_port, "tcp://127.0.0.1:9", "tcp://127.0.0.1:9",
                                                           health))
    setup = Setup(default_rig(), [RadarLink("left_front", free_port(socket.SOCK_DGRAM))], health_endpoint=health,
                  health_interval_s=0.5, workers=[view])
    until, outcome = threading.Event(), {}

    def viewer():
        try:
            deadline = time.monotonic() + 120
            while True:  # the view worker listens once it is warm
                try:
                    socket.create_connection(("127.0.0.1", view_port), timeout=1).close()
                    break
                except OSError:
                    assert time.monotonic() < deadline, "the live view never listened"
                    time.sleep(0.2)
            proc = subprocess.Popen([*node_client, f"ws://127.0.0.1:{view_port}", "foxglove.websocket.v1", "40",
                                     "/events=exited with code -9", "/health"], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            lines = _lines(proc)
            while not any(json.loads(line).get("topic") == "/health" for line in list(lines.queue)):
                time.sleep(0.1)
                assert time.monotonic() < deadline and proc.poll() is None, "no health reached the client"
            driver = _descendant_named("sarbot-left_front"[:15])  # the name the driver gives itself
            assert driver is not None, "the radar driver process was not found"
            os.kill(driver, signal.SIGKILL)
            proc.wait(timeout=45)
            outcome["returncode"] = proc.returncode
            outcome["lines"] = [json.loads(line) for line in lines.rest()]
        except BaseException as e:  # noqa: BLE001 - reported by the test below
            outcome["error"] = e
        finally:
            until.set()

    thread = threading.Thread(target=viewer)
    thread.start()
    (path,) = record(setup, tmp_path, until=until)
    thread.join()
    assert "error" not in outcome, outcome.get("error")
    assert outcome["returncode"] == 0
    shown = [d["message"] for d in outcome["lines"] if d.get("topic") == "/events" and "message" in d]
    restart = [m for m in shown if "exited with code -9" in m["message"]]
    assert len(restart) == 1 and restart[0]["name"] == "radar.left_front" and restart[0]["level"] == 4  # ERROR
    with Recording(path) as rec:
        in_file = [e for e in rec.events() if "exited with code -9" in e[3]]
    assert [(e[1], e[3]) for e in in_file] == [("radar.left_front", restart[0]["message"])]
