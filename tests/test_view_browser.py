"""The live map in a browser: a page subscribes to /map on the view worker's Foxglove WebSocket server,
draws the received foxglove.Grid on a canvas, and headless Chromium's screenshot of it is compared with
the map that was sent, cell by cell. Runs where Chromium is installed (``.ci/run`` installs it)."""

from __future__ import annotations

import base64
import io
import json
import shutil
import subprocess
import time
import urllib.request

import numpy as np
import pytest

from acquisition.messages import MapTile
from acquisition.processes import free_port
from acquisition.workers.view import ViewWorker, ViewWorkerConfig

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (apt-get install chromium)")

SCALE = 8  # canvas pixels per grid cell
FLOOR_DB = -40.0  # black; 0 dB is white

PAGE = """<!doctype html>
<html><body style="margin:0;background:#123">
<canvas id="map"></canvas>
<script>
// A minimal Foxglove WebSocket client: subscribe to /map, decode foxglove.Grid, draw its "db" field in grey,
// FLOOR dB black to 0 dB white, north (growing y, growing row) up.
const FLOOR = %(floor)s, SCALE = %(scale)s;
const ws = new WebSocket("ws://127.0.0.1:" + new URLSearchParams(location.search).get("port"), ["foxglove.sdk.v1", "foxglove.websocket.v1"]);
ws.binaryType = "arraybuffer";
ws.onmessage = (ev) => {
  if (typeof ev.data === "string") {
    const m = JSON.parse(ev.data);
    if (m.op === "advertise") for (const c of m.channels) if (c.topic === "/map" && c.schemaName === "foxglove.Grid") {
      ws.send(JSON.stringify({op: "subscribe", subscriptions: [{id: 7, channelId: c.id}]}));
      document.title = "subscribed";
    }
    return;
  }
  const view = new DataView(ev.data);
  if (view.getUint8(0) === 1 && view.getUint32(1, true) === 7) render(new Uint8Array(ev.data, 13));
};
function fields(b) {  // protobuf: field number -> values (varint: number, others: bytes)
  const out = {}; let i = 0;
  const varint = () => { let v = 0, s = 0, x; do { x = b[i++]; v += (x & 0x7f) * 2 ** s; s += 7; } while (x & 0x80); return v; };
  while (i < b.length) {
    const key = varint(), n = Math.floor(key / 8), w = key & 7; let v;
    if (w === 0) v = varint();
    else if (w === 2) { const len = varint(); v = b.subarray(i, i + len); i += len; }
    else if (w === 5) { v = b.subarray(i, i + 4); i += 4; }
    else if (w === 1) { v = b.subarray(i, i + 8); i += 8; }
    else throw new Error("wire type " + w);
    (out[n] = out[n] || []).push(v);
  }
  return out;
}
const u32 = (b) => new DataView(b.buffer, b.byteOffset, 4).getUint32(0, true);
function render(msg) {
  const f = fields(msg);
  const cols = u32(f[4][0]), rowStride = u32(f[6][0]), cellStride = u32(f[7][0]);
  const data = f[9][0], rows = data.length / rowStride;
  const dv = new DataView(data.buffer, data.byteOffset, data.length);
  const small = document.createElement("canvas"); small.width = cols; small.height = rows;
  const sctx = small.getContext("2d"), img = sctx.createImageData(cols, rows);
  for (let r = 0; r < rows; r++) for (let c = 0; c < cols; c++) {
    const db = dv.getFloat32(r * rowStride + c * cellStride, true);
    const g = Math.round(255 * Math.min(1, Math.max(0, (db - FLOOR) / -FLOOR)));
    const p = 4 * ((rows - 1 - r) * cols + c);
    img.data[p] = img.data[p + 1] = img.data[p + 2] = g; img.data[p + 3] = 255;
  }
  sctx.putImageData(img, 0, 0);
  const canvas = document.getElementById("map");
  canvas.width = cols * SCALE; canvas.height = rows * SCALE;
  const ctx = canvas.getContext("2d"); ctx.imageSmoothingEnabled = false;
  ctx.drawImage(small, 0, 0, canvas.width, canvas.height);
  document.title = "rendered " + cols + "x" + rows;
}
</script></body></html>
"""


class DevTools:
    """Just enough of the Chrome DevTools Protocol: evaluate an expression, take a screenshot."""

    def __init__(self, ws):
        self.ws = ws
        self.next_id = 0

    def call(self, method: str, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            reply = json.loads(self.ws.recv(timeout=10))
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def wait_for(self, predicate, timeout_s: float = 15.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            title = self.evaluate("document.title")
            if predicate(title):
                return title
            time.sleep(0.05)
        raise AssertionError(f"the page did not get there in {timeout_s} s (title {title!r})")


@pytest.fixture
def chromium(tmp_path):
    proc = subprocess.Popen([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                             "--disable-background-networking", "--disable-component-update", "--disable-sync",
                             "--hide-scrollbars", "--window-size=800,600", f"--user-data-dir={tmp_path / 'profile'}",
                             "--remote-debugging-port=0", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        for line in proc.stderr:
            if "DevTools listening on" in line:
                port = int(line.split("ws://", 1)[1].split("/", 1)[0].rsplit(":", 1)[1])
                break
            if time.monotonic() > deadline:
                raise AssertionError("Chromium did not start its DevTools server")
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
            page = next(t for t in json.load(r) if t["type"] == "page")
        from websockets.sync.client import connect

        with connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
            yield DevTools(ws)
    finally:
        proc.kill()
        proc.wait(timeout=10)


def test_a_browser_page_draws_the_map_it_receives(tmp_path, chromium):
    import matplotlib.image

    port = free_port()
    worker = ViewWorker(ViewWorkerConfig("127.0.0.1", port, "tcp://unused:1", "tcp://unused:2", "tcp://unused:3"), None)
    worker.warm_up()
    # A 2 x 2-tile map: dim background (-60 dB, black), one target at 0 dB near the east edge low, one at
    # -20 dB in the north-west, a ramp from -40 to 0 dB along the bottom row.
    n = 16
    mosaic = np.full((2 * n, 2 * n), 1e-3, np.float32)
    mosaic[4:8, 20:28] = 1.0
    mosaic[24:28, 2:6] = 0.1
    mosaic[0, :] = 10 ** (np.linspace(-40, 0, 2 * n) / 20)
    page = tmp_path / "view.html"
    page.write_text(PAGE % {"floor": FLOOR_DB, "scale": SCALE})
    try:
        chromium.call("Page.navigate", url=f"file://{page}?port={port}")
        chromium.wait_for(lambda t: t == "subscribed")
        for ix in range(2):
            for iy in range(2):
                tile = mosaic[iy * n:(iy + 1) * n, ix * n:(ix + 1) * n].astype(np.complex64)
                worker.handle(MapTile((ix, iy), 0.01, n, tile), live=True)
        worker.step()
        assert chromium.wait_for(lambda t: t.startswith("rendered")) == "rendered 32x32"
        shot = chromium.call("Page.captureScreenshot", format="png",
                             clip={"x": 0, "y": 0, "width": 2 * n * SCALE, "height": 2 * n * SCALE, "scale": 1})
    finally:
        worker.write_products()
    png = base64.b64decode(shot["data"])
    (tmp_path / "view.png").write_bytes(png)  # to look at: pytest --basetemp=DIR
    pixels = matplotlib.image.imread(io.BytesIO(png), format="png")
    assert pixels.shape[:2] == (2 * n * SCALE, 2 * n * SCALE)
    # The centre of every drawn cell, back in grid order (row 0 at the bottom of the screen).
    cells = pixels[SCALE // 2::SCALE, SCALE // 2::SCALE, :3][::-1]
    assert np.ptp(cells, axis=-1).max() < 1e-6  # grey
    expected = np.clip((20 * np.log10(mosaic / mosaic.max()) - FLOOR_DB) / -FLOOR_DB, 0, 1)
    np.testing.assert_allclose(cells[..., 0], np.round(expected * 255) / 255, atol=1.5 / 255)
    assert cells[4:8, 20:28, 0].min() == 1.0 and cells[24:28, 2:6, 0].mean() == pytest.approx(0.5, abs=0.01)
