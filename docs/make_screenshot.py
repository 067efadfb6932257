"""Make docs/images/live_view.png: a strip map served by the live view (``sarbot run --view``), drawn by a
browser page that subscribes to its Foxglove WebSocket channel ``/map``, screenshot by headless Chromium.

    python3 dev.py demo                                   # makes sarbot-demo/stripmap_demo.h5
    .venv/bin/python docs/make_screenshot.py [--map sarbot-demo/stripmap_demo.h5] [--output docs/images/live_view.png]

The map file's tiles go to the view worker exactly as the strip-map worker sends them (``map/tile``), so the
picture is what a viewer connected to a run shows of that map. Needs Chromium (``apt-get install chromium``)
and the test extra (``websockets``). The page and the DevTools calls are those of tests/test_view_browser.py.
"""

from __future__ import annotations

import argparse
import base64
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FLOOR_DB = -40.0

PAGE = """<!doctype html>
<html><body style="margin:0;background:#123;color:#ddd;font:14px sans-serif">
<div style="padding:6px 10px">live view: <b>/map</b>, foxglove.Grid in dB</div>
<canvas id="map"></canvas>
<script>
// The minimal Foxglove WebSocket client of tests/test_view_browser.py: subscribe to /map, decode foxglove.Grid, draw its "db" field in grey,
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
    const v = Math.min(1, Math.max(0, (db - FLOOR) / -FLOOR));
    const p = 4 * ((rows - 1 - r) * cols + c);
    // black - red - yellow - white, FLOOR dB to 0 dB
    img.data[p] = Math.round(255 * Math.min(1, 3 * v)); img.data[p + 1] = Math.round(255 * Math.min(1, Math.max(0, 3 * v - 1)));
    img.data[p + 2] = Math.round(255 * Math.max(0, 3 * v - 2)); img.data[p + 3] = 255;
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
            reply = json.loads(self.ws.recv(timeout=30))
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def wait_for_title(self, predicate, timeout_s: float = 30.0) -> str:
        deadline = time.monotonic() + timeout_s
        title = ""
        while time.monotonic() < deadline:
            title = self.call("Runtime.evaluate", expression="document.title", returnByValue=True)["result"].get("value")
            if predicate(title):
                return title
            time.sleep(0.05)
        raise RuntimeError(f"the page did not get there in {timeout_s} s (title {title!r})")


def map_tiles(path: Path):
    """The strip map file's tiles as the strip-map worker publishes them: (key, pixel_m, tile_px, complex tile)."""
    from imaging.io.image_file import read_image

    img = read_image(path)
    n = int(img.attrs["tile_px"])
    pixel_m = float(img.x_m[1] - img.x_m[0])
    tile_m = n * pixel_m
    ix0 = int(round((img.x_m[0] - pixel_m / 2) / tile_m))
    iy0 = int(round((img.y_m[0] - pixel_m / 2) / tile_m))
    image = np.asarray(img.image, np.complex64)
    for ty in range(image.shape[0] // n):
        for tx in range(image.shape[1] // n):
            tile = image[ty * n:(ty + 1) * n, tx * n:(tx + 1) * n]
            if np.any(tile):
                yield (ix0 + tx, iy0 + ty), pixel_m, n, tile


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", type=Path, default=ROOT / "sarbot-demo" / "stripmap_demo.h5")
    ap.add_argument("--output", type=Path, default=ROOT / "docs" / "images" / "live_view.png")
    ap.add_argument("--width", type=int, default=900, help="screenshot width, pixels")
    args = ap.parse_args(argv)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if chromium is None:
        print("make_screenshot: Chromium is not installed (apt-get install chromium)", file=sys.stderr)
        return 2
    if not args.map.is_file():
        print(f"make_screenshot: {args.map}: no such file (python3 dev.py demo makes one)", file=sys.stderr)
        return 2
    from websockets.sync.client import connect

    from acquisition.messages import MapTile
    from acquisition.processes import free_port
    from acquisition.workers.view import ViewWorker, ViewWorkerConfig

    tiles = list(map_tiles(args.map))
    keys = np.array([k for k, *_ in tiles])
    n = tiles[0][2]
    cols = int(keys[:, 0].max() - keys[:, 0].min() + 1) * n
    rows = int(keys[:, 1].max() - keys[:, 1].min() + 1) * n
    scale = max(1, args.width // cols)
    port = free_port()
    worker = ViewWorker(ViewWorkerConfig("127.0.0.1", port, "tcp://unused:1", "tcp://unused:2", "tcp://unused:3"), None)
    worker.warm_up()
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "view.html"
        page.write_text(PAGE % {"floor": FLOOR_DB, "scale": scale})
        proc = subprocess.Popen([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                                 "--hide-scrollbars", f"--window-size={cols * scale},{rows * scale + 40}",
                                 f"--user-data-dir={Path(tmp) / 'profile'}", "--remote-debugging-port=0",
                                 "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            for line in proc.stderr:
                if "DevTools listening on" in line:
                    devtools_port = int(line.split("ws://", 1)[1].split("/", 1)[0].rsplit(":", 1)[1])
                    break
            with urllib.request.urlopen(f"http://127.0.0.1:{devtools_port}/json/list", timeout=10) as r:
                target = next(t for t in json.load(r) if t["type"] == "page")
            with connect(target["webSocketDebuggerUrl"], max_size=None) as ws:
                tools = DevTools(ws)
                tools.call("Page.navigate", url=f"file://{page}?port={port}")
                tools.wait_for_title(lambda t: t == "subscribed")
                for key, pixel_m, tile_px, tile in tiles:
                    worker.handle(MapTile(key, pixel_m, tile_px, tile), live=True)
                worker.step()
                tools.wait_for_title(lambda t: t.startswith("rendered"))
                shot = tools.call("Page.captureScreenshot", format="png",
                                  clip={"x": 0, "y": 0, "width": cols * scale, "height": rows * scale + 30, "scale": 1},
                                  captureBeyondViewport=True)
        finally:
            worker.write_products()
            proc.kill()
            proc.wait(timeout=10)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_bytes(base64.b64decode(shot["data"]))
    print(f"wrote {args.output} ({len(tiles)} tiles, {cols} x {rows} cells)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
