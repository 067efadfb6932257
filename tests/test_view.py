"""The live view worker on a real Foxglove WebSocket server, read by a WebSocket client speaking the protocol.

(The whole pipeline with ``--view`` is in tests/test_demo.py.)"""

import asyncio
import json
import struct

import numpy as np
import pytest

from acquisition.messages import Event, ImuBatch, MapTile, PointCloudMessage, PoseBatch
from acquisition.processes import free_port
from acquisition.workers.view import ViewWorker, ViewWorkerConfig, parse_view_address
from imaging.core.errors import SarbotError


def protobuf_fields(buf: bytes) -> dict[int, list]:
    """The top-level fields of a protobuf message: number -> values (varints as int, the rest as bytes)."""
    out: dict[int, list] = {}
    i = 0

    def varint():
        nonlocal i
        shift = value = 0
        while True:
            b = buf[i]
            i += 1
            value |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                return value

    while i < len(buf):
        key = varint()
        number, wire = key >> 3, key & 7
        if wire == 0:
            value = varint()
        elif wire == 2:
            n = varint()
            value, i = buf[i:i + n], i + n
        elif wire == 1:
            value, i = buf[i:i + 8], i + 8
        elif wire == 5:
            value, i = buf[i:i + 4], i + 4
        else:
            raise ValueError(f"wire type {wire}")
        out.setdefault(number, []).append(value)
    return out


async def _watch(port, feed, n_expected):
    import websockets

    got: dict[str, list[bytes]] = {}
    async with websockets.connect(f"ws://127.0.0.1:{port}", max_size=None,
                                  subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
        channels = {}
        while not channels:
            d = json.loads(await asyncio.wait_for(ws.recv(), 5))
            if d["op"] == "advertise":
                channels = {c["id"]: c for c in d["channels"]}
        await ws.send(json.dumps({"op": "subscribe",
                                  "subscriptions": [{"id": cid, "channelId": cid} for cid in channels]}))
        await asyncio.sleep(0.3)
        feed()
        while sum(len(v) for v in got.values()) < n_expected:
            m = await asyncio.wait_for(ws.recv(), 5)
            if isinstance(m, bytes) and m[0] == 1:
                (sub,) = struct.unpack_from("<I", m, 1)
                got.setdefault(channels[sub]["topic"], []).append(m[13:])
    return channels, got


def test_the_map_arrives_as_a_grid_in_db_with_pose_tf_and_events():
    port = free_port()
    mounts = {"left_front": ([0.15, 0.2, 0.3], [0.0, 0.0, 0.7071068, 0.7071068])}
    worker = ViewWorker(ViewWorkerConfig("127.0.0.1", port, "tcp://unused:1", "tcp://unused:2", "tcp://unused:3",
                                         mounts=mounts), None)
    worker.warm_up()
    rng = np.random.default_rng(0)
    xyz, doppler = rng.normal(size=(5, 3)).astype(np.float32), rng.normal(size=5).astype(np.float32)
    tiles = {(2, 5): (rng.normal(size=(16, 16)) + 1j * rng.normal(size=(16, 16))).astype(np.complex64),
             (3, 5): (rng.normal(size=(16, 16)) + 1j * rng.normal(size=(16, 16))).astype(np.complex64)}

    def feed():
        for key, image in tiles.items():
            worker.handle(MapTile(key, 0.01, 16, image), live=True)
        worker.handle(PoseBatch(np.array([7_000_000_123], np.int64), np.array([[1.0, 2.0, 0.0]]),
                                np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3))), live=True)
        worker.handle(Event(5, "radar.left_front", "warning", "kernel dropped 3 datagram(s)"), live=True)
        worker.handle(PointCloudMessage("left_front", 7_000_000_000, xyz, doppler), live=True)
        worker.handle(ImuBatch(np.array([7_000_000_000], np.int64), np.array([[0.1, 0.2, 0.3]], np.float32),
                               np.array([[0.0, 0.0, 9.81]], np.float32), np.zeros(1, np.uint32),
                               np.array([7_000_000_000], np.int64), None), live=True)
        worker.step()

    try:
        channels, got = asyncio.run(_watch(port, feed, n_expected=6))
    finally:
        worker.write_products()
    topics = {c["topic"]: c["schemaName"] for c in channels.values()}
    assert topics["/map"] == "foxglove.Grid" and topics["/events"] == "foxglove.Log" and topics["/tf"] == "foxglove.FrameTransforms"
    (grid,) = got["/map"]
    fields = protobuf_fields(grid)
    assert struct.unpack("<I", fields[4][0]) == (32,)  # column_count (fixed32): two tiles side by side
    db = np.frombuffer(fields[9][0], "<f4").reshape(16, 32)
    mosaic = np.abs(np.hstack([tiles[(2, 5)], tiles[(3, 5)]]))
    np.testing.assert_allclose(db, 20 * np.log10(mosaic / mosaic.max()), atol=1e-4)
    assert b"kernel dropped 3 datagram(s)" in got["/events"][0]
    assert len(got["/pose"]) == 1 and len(got["/tf"]) == 1
    assert b"left_front" in got["/tf"][0]  # base_link -> the radar, by its mount
    (cloud,) = got["/radar/left_front/points"]
    packed = protobuf_fields(cloud)[6][0]  # foxglove.PointCloud.data
    np.testing.assert_array_equal(np.frombuffer(packed, "<f4").reshape(5, 4), np.column_stack([xyz, doppler]))
    imu = json.loads(got["/imu"][0])
    assert imu["time_ns"] == 7_000_000_000 and imu["accel_mps2"][2] == pytest.approx(9.81, abs=1e-5)
    assert worker.counters() == {"sent_map": 1, "sent_pose": 1, "sent_health": 0, "sent_events": 1, "sent_points": 1,
                                 "sent_imu": 1}


def test_a_large_map_is_sent_coarser_keeping_its_brightest_pixels():
    from acquisition.workers.view import block_max

    image = np.zeros((1000, 3001), np.float32)
    image[517, 2999] = 5.0
    small, k = block_max(image, 400_000)
    assert k == 3 and small.shape == (334, 1001) and small.size <= 400_000
    assert small[517 // 3, 2999 // 3] == 5.0 and small.sum() == 5.0
    same, k1 = block_max(image, image.size)
    assert k1 == 1 and same is image


@pytest.mark.parametrize("text, expected", [("8765", ("127.0.0.1", 8765)), ("0.0.0.0:9000", ("0.0.0.0", 9000))])
def test_view_address(text, expected):
    assert parse_view_address(text) == expected


@pytest.mark.parametrize("text", ["", "host:", "70000", "x:0", "abc"])
def test_bad_view_address(text):
    with pytest.raises(SarbotError, match="--view"):
        parse_view_address(text)
