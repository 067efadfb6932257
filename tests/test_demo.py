"""`sarbot demo`, the README's main job: the whole pipeline on emulated hardware, checked end to end."""

import asyncio
import json
import os
import re
import struct
import subprocess
import sys
import threading

import h5py
import numpy as np

from imaging.io.recording import Recording

CLI = [sys.executable, "-m", "acquisition.cli"]


class FoxgloveClient(threading.Thread):
    """A Foxglove WebSocket client (the protocol Foxglove speaks): connects as soon as the server is up,
    subscribes to every channel it advertises and keeps what comes, by topic."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        self.port = port
        self.channels: dict[int, dict] = {}
        self.messages: dict[str, list[bytes]] = {}
        self.stop = threading.Event()

    def run(self):
        asyncio.run(self._run())

    async def _run(self):
        import websockets

        while not self.stop.is_set():
            try:
                async with websockets.connect(f"ws://127.0.0.1:{self.port}", max_size=None,
                                              subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
                    while not self.stop.is_set():
                        try:
                            m = await asyncio.wait_for(ws.recv(), 0.5)
                        except asyncio.TimeoutError:
                            continue
                        if isinstance(m, str):
                            d = json.loads(m)
                            if d["op"] == "advertise":
                                new = [c for c in d["channels"] if c["id"] not in self.channels]
                                self.channels.update({c["id"]: c for c in new})
                                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                    {"id": c["id"], "channelId": c["id"]} for c in new]}))
                        elif m[0] == 1:  # message data: opcode, subscription id u32, log time u64, payload
                            (sub,) = struct.unpack_from("<I", m, 1)
                            self.messages.setdefault(self.channels[sub]["topic"], []).append(m[13:])
            except (OSError, websockets.exceptions.WebSocketException):
                await asyncio.sleep(0.2)  # not up yet (the demo simulates first), or gone at the end


def test_demo_runs_the_whole_pipeline_and_finds_the_targets(tmp_path):
    """On a cold JIT cache, as on a fresh machine: the first run must pass too (the workers compile their
    kernels before the daemon says it is ready, and the hardware starts then). Watched live on the Foxglove
    WebSocket protocol (``--view``): the client gets the map as it grows, the pose and the health."""
    from acquisition.processes import free_port

    out = tmp_path / "demo"
    cache = tmp_path / "empty-jit-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    out.mkdir()
    (out / "my_notes.md").write_text("the user's own file, in the folder the demo writes to\n")
    port = free_port()
    client = FoxgloveClient(port)
    client.start()
    res = subprocess.run([*CLI, "demo", "-o", str(out), "--view", str(port)], capture_output=True, text=True,
                         timeout=600, env=env)
    client.stop.set()
    client.join(5)
    assert (out / "my_notes.md").read_text().startswith("the user's own file")  # the demo deletes only its own
    assert any(cache.rglob("*.nbi")), "the run compiled into the empty cache"
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "Traceback" not in res.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["ok"]
    # Nothing lost between the emulated hardware and the file.
    for name, (got, sent) in report["frames_recorded_of_sent"].items():
        assert got == sent == 192, name
    assert report["imu_samples_recorded_of_sent"][0] == report["imu_samples_recorded_of_sent"][1]
    assert report["can_frames_recorded_of_sent"][0] == report["can_frames_recorded_of_sent"][1]
    # The emulated devices are plugged in before the daemon starts and until it has stopped, as a robot's are:
    # no warning in the file (the IMU's port had been missing at the start and lost at the end). The odometry
    # may thin a few radar scans where the machine is briefly short of CPU, as designed and said in /events
    # (the fresh-clone CI on the 2-vCPU AMD VM: one scan, 0.4 s behind): a few, never more.
    behind = [e for e in report["events"] if e[0] == "rio" and " behind: " in e[2]]
    assert not [e for e in report["events"] if e[1] != "info" and e not in behind], report["events"]
    thinned = [int(re.search(r"(\d+) radar scans thinned", e[2]).group(1)) for e in behind]
    assert max(thinned, default=0) <= 8, behind
    with Recording(out / "recording.h5") as rec, Recording(out / "simulated.h5") as sim:
        np.testing.assert_array_equal(rec.file["radar/left_front/adc"][()], sim.file["radar/left_front/adc"][()])
    # The odometry from raw ADC and IMU, and the live map placed by it.
    assert report["odometry"]["distance_m"] > 2.5 and report["odometry"]["final_drift_m"] < 0.05
    assert sorted(t["target"] for t in report["targets"]) == ["corner reflector, left", "corner reflector, right", "rod, left"]
    for t in report["targets"]:
        assert t["error_m"] < 0.03, t
        assert 0.8 < t["cross_range_width_m"] / t["cross_range_theory_m"] < 1.5, t
    with h5py.File(out / "stripmap_demo.h5") as f:
        assert f.attrs["schema"] == "sarbot.image" and f.attrs["trajectory_source"] == "rio"
        # All four radars, both sides: every frame imaged, or left out as adding no aperture (the first 2 s,
        # standing), or at the very end beyond the odometry's last pose, or (a machine far behind) thinned;
        # none dropped.
        a = f.attrs
        assert a["radars"] == "left_front,left_rear,right_front,right_rear"
        assert (a["frames_imaged"] + a["frames_standing_still"] + a["frames_beyond_odometry"]
                + a["frames_thinned"] == 4 * 192), dict(a)
        assert a["frames_dropped_behind"] == 0 and a["frames_skipped_invalid"] == 0 and a["frames_lost_on_bus"] == 0
        assert a["frames_standing_still"] >= 140 and a["frames_beyond_odometry"] <= 4 * 4
        # Follows the drive: about 5 s here, warm or cold (cold without the warm-up it was 26-32 s).
        assert 0 < f.attrs["max_lag_s"] < 15.0
    assert (out / "stripmap_demo.png").stat().st_size > 10_000
    assert "report.md" in res.stdout
    # What the live view served while the demo ran.
    schemas = {c["topic"]: c["schemaName"] for c in client.channels.values()}
    assert schemas["/map"] == "foxglove.Grid" and schemas["/pose"] == "foxglove.PoseInFrame"
    assert len(client.messages["/map"]) >= 5, {k: len(v) for k, v in client.messages.items()}
    sizes = [len(m) for m in client.messages["/map"]]
    assert sizes[-1] > 4 * 64 * 64 and sizes[-1] >= sizes[0]  # the mosaic grows as the drive goes on
    assert len(client.messages["/pose"]) >= 20 and len(client.messages["/tf"]) >= 20
    for radar in ("left_front", "left_rear", "right_front", "right_rear"):  # the odometry's detections
        assert len(client.messages.get(f"/radar/{radar}/points", [])) >= 10, radar
    assert len(client.messages["/imu"]) >= 20
    health = [json.loads(m) for m in client.messages["/health"]]
    assert len(health) >= 5 and "left_front" in health[-1]["frames_per_s"] and "summary" in health[-1]


def test_run_without_an_imu_is_a_one_line_error(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text("[radar.left]\n")
    res = subprocess.run([*CLI, "run", "--config", str(rig), "-o", str(tmp_path), "--radar", "left=40000"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "--imu-port" in res.stderr


def test_the_jit_cache_goes_where_systemd_says(tmp_path):
    """Under the unit (ProtectSystem=strict) numba cannot cache beside the sources; sarbot puts the cache
    in the unit's CacheDirectory (systemd passes it as $CACHE_DIRECTORY)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["CACHE_DIRECTORY"] = str(tmp_path / "cache")
    res = subprocess.run([*CLI, "simulate", "point_target", "-o", str(tmp_path / "p.h5")], capture_output=True,
                         text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr
    assert any((tmp_path / "cache" / "numba").rglob("*.nbi"))
