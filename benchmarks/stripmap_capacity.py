"""The live map's capacity: the strip-map worker's CPU per frame, part by part, for the four-radar soak at
1x, and the fraction of one core that needs.

    python benchmarks/stripmap_capacity.py [--seconds 12] [--repeats 2]

Load-independent: everything runs in this one process and is counted in CPU time (``time.process_time``),
not wall time, so what other processes take of the machine does not enter (beyond what sharing the caches
costs; the load average is recorded). On this two-core machine the soak runs four emulated radars, the
IMU, their drivers, the recorder and the odometry beside the map: its wall-clock lag says whether the map
got a core, this says how much of one it needs.

Data: the soak's scene (``soak_loop``, all four radars of the reference rig at the reference waveform, its
first 12 s: standing 2 s, then a 1.6 m straight and most of a half circle at 0.4 m/s), simulated once; the
frames from 2.5 s on (the robot driving) are measured. The worker is the daemon's own
(``acquisition.workers.stripmap.StripMapWorker``) with ``sarbot run``'s map settings (the soak's: polar,
0.3 m aperture, 1 cm pixels, 1 to 4 m, pre-summing 'auto' at 0.5 m/s) and the kernel on one thread. Every
frame goes through what the live worker does with it: the bus message decoded (msgpack header, array
views, the typed message; the socket's own copy is not counted), queued, and imaged once poses cover it;
poses come as the odometry sends them, in batches of ``POSE_BATCH_S`` held back ``POSE_HOLD_S`` behind the
radars (the truth trajectory stands in for the odometry's); tiles and status go out every
``PUBLISH_EVERY_S`` of sensor time on a real publisher with no subscriber (as in the soak, where nobody takes
tiles).

Each part's CPU is timed exclusively (a part called inside another is not counted twice) by wrapping the
functions the worker calls: the bus decode, the worker's queueing, pre-summing, antenna placement, range
compression (the direct path's profiles; the polar path's beam signals), the polar beams (their weights, the
product over the chirps), the beams read at the pixels (or the direct kernel), footprints (tiles and pixel
masks), the tile updates, the rest of ``add_frames`` (pixel lists, centres and looks), the worker's
imaging loop, publishing.
Refocus is off in the soak (``--map-refocus none``, the default): its cost is measured apart on a few
frames. The sum of the parts is checked against the whole loop's CPU.

The cuts this issue made are measured against the code they replaced (kept here, ``BEFORE``), and the latest
round's against the code before it alone (``PREVIOUS``): three workers, one on each, take every message in
turn, so the machine's load falls on all alike (CPU time still grows with it: the caches are shared with
others' work; the load average is recorded).

Writes docs/results/stripmap_capacity.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.bus import BusPublisher, Message  # noqa: E402
from acquisition.messages import PoseBatch, RadarFrameMessage, decode  # noqa: E402
from acquisition.processes import bus_endpoint  # noqa: E402
from acquisition.workers import pipeline  # noqa: E402
from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig  # noqa: E402
from drivers.radar.stream import RadarFrame  # noqa: E402
from imaging.core.rig import load_rig  # noqa: E402
from imaging.core.trajectory import SampledTrajectory  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.stripmap import StripMapConfig  # noqa: E402
import imaging.profiles  # noqa: E402
import imaging.stripmap.footprint as stripmap_footprint  # noqa: E402
import imaging.stripmap.map as stripmap_map  # noqa: E402
import imaging.stripmap.polar as stripmap_polar  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RIG = ROOT / "imaging" / "rigs" / "default.toml"
RADARS = ["left_front", "left_rear", "right_front", "right_rear"]
#: ``sarbot run``'s map options at their defaults (acquisition/cli/daemon.py), as the soak runs it
MAP = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.0, range_max_m=4.0, z_m=0.3)
MAX_SPEED_MPS = 0.5
#: The odometry's poses: a batch per IMU message, held back behind the radars (its wait for every radar's
#: scan, 0.04 s median in the soak: acquisition/workers/stripmap.py)
POSE_BATCH_S = 0.01
POSE_HOLD_S = 0.04
PUBLISH_EVERY_S = 0.5  # StripMapWorker.step's
#: The lap's first seconds left out: standing still 2 s (frames skipped at almost no cost), then the
#: start; what is measured is the robot driving (a straight and a half circle), as the map needs it.
DRIVING_FROM_S = 2.5
_sample = SampledTrajectory.sample  # the poses' making is not the worker's: unwrapped


class Parts:
    """Exclusive CPU seconds per named part: a part's time less that of the parts called inside it."""

    def __init__(self):
        self.s: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._stack: list[list[float]] = []

    def enter(self) -> None:
        self._stack.append([time.process_time(), 0.0])

    def leave(self, name: str) -> None:
        start, inner = self._stack.pop()
        spent = time.process_time() - start
        self.s[name] = self.s.get(name, 0.0) + spent - inner
        self.calls[name] = self.calls.get(name, 0) + 1
        if self._stack:
            self._stack[-1][1] += spent

    def wrap(self, name: str, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            self.enter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.leave(name)
        return timed


#: (module or class, attribute, part): what the worker calls, where it looks the name up
TIMED = [
    (stripmap_map, "presum_chirps", "presum"),
    (stripmap_map, "antenna_track", "antenna placement"),
    (imaging.profiles, "antenna_track", "antenna placement"),
    (stripmap_map, "chirp_profiles", "range compression (direct: profiles)"),
    (stripmap_polar, "fft_in_place", "range compression (polar: beam signals' FFT)"),
    (stripmap_polar, "_weights", "polar beams: weights"),
    (stripmap_polar, "_extent", "polar beams: pixel extent"),
    (stripmap_map, "masked_extent", "polar beams: pixel extent"),
    (stripmap_map, "frame_beams", "polar beams: set-up"),
    (stripmap_polar, "frame_beams_over", "polar beams: product over the chirps, signals"),
    (stripmap_map, "frame_beams_over", "polar beams: product over the chirps, signals"),
    (stripmap_map, "beams_at_points", "pixels: beams read at the pixels (polar)"),
    (stripmap_map, "beams_at_masked", "pixels: beams read at the pixels (polar)"),
    (stripmap_map, "backproject", "pixels: direct kernel"),
    (stripmap_map.StripMap, "_footprints", "footprint (tiles, pixel masks)"),
    (stripmap_map.StripMap, "frames_profiles", "profiles rest (chirp times, looks, stacking)"),
    (stripmap_map.StripMap, "_polar_takers", "polar: frames' pixel selection"),
    (stripmap_map.StripMap, "_polar_masked", "polar: one frame's tiles stacked"),
    (stripmap_map.StripMap, "_pixel_values", "pixel lists"),
    (SampledTrajectory, "sample", "trajectory sampling"),
    (SampledTrajectory, "velocity", "trajectory sampling"),
    (stripmap_map.StripMap, "_add_to_tiles", "tile updates (values added at the masked pixels)"),
    (stripmap_map.StripMap, "add_frames", "add_frames rest (centres and looks, moving check)"),
    (StripMapWorker, "_trajectory", "worker: poses into a trajectory"),
    (StripMapWorker, "_image_ready", "worker: imaging loop rest (batching, catch-up, accounting)"),
    (StripMapWorker, "handle", "worker: queueing frames and poses"),
    (StripMapWorker, "_publish_tiles", "publish (changed tiles, status)"),
]


@dataclasses.dataclass
class Pass:
    parts: dict
    whole_cpu_s: float
    frames: int
    sensor_s: float
    status: dict
    batch_sizes: dict


def simulate(seconds: float, work: Path) -> Path:
    """The scene's recording in ``work`` (kept there: a later run with the same ``--work`` reuses it)."""
    path = work / f"soak_loop_{seconds:g}s.h5"
    if not path.exists():
        scene = dataclasses.replace(load_scene("soak_loop"), radars=RADARS, duration_s=seconds, imu=False)
        simulate_recording(scene, work / "partial.h5", overwrite=True)
        (work / "partial.h5").rename(path)
    return path


def frame_message_bytes(radar: str, counter: int, t_ns: int, iq: np.ndarray) -> list:
    """A frame as it crosses the bus (``acquisition.bus``): topic, msgpack header, the array's bytes."""
    parts = RadarFrameMessage(radar, RadarFrame(counter, t_ns, t_ns, True, 0, iq)).to_parts()
    header = {"seq": counter, "pub": "bench", "sensor_time_ns": int(parts.sensor_time_ns), "host_time_ns": t_ns,
              "arrays": [[a.dtype.str, list(a.shape)] for a in parts.arrays], **parts.fields}
    return [parts.topic.encode(), msgpack.packb(header, use_bin_type=True), *[a.tobytes() for a in parts.arrays]]


def receive(parts: list) -> Message:
    """What ``BusSubscriber.receive`` does with a message's parts (its socket copy aside)."""
    topic = bytes(parts[0]).decode()
    header = msgpack.unpackb(parts[1], raw=False)
    arrays = [np.frombuffer(p, dtype=np.dtype(dt)).reshape(shape) for p, (dt, shape) in zip(parts[2:], header["arrays"])]
    return Message(topic, header["seq"], header["sensor_time_ns"], header["host_time_ns"], header, arrays)


def events(rec: Recording, radars: list[str], from_s: float):
    """(sensor time the message is available, kind, payload) in time order from ``from_s`` into the
    recording: a frame when it ends, a pose batch ``POSE_HOLD_S`` after its last pose."""
    truth = rec.truth()
    t0, t1 = int(truth.time_ns[0]) + int(from_s * 1e9), int(truth.time_ns[-1])
    out = []
    for name in radars:
        t = rec.frame_time_ns(name)
        frame_ns = rec.radar(name).waveform.frame_duration_ns
        out += [(int(t[k]) + frame_ns, 0, (name, k)) for k in range(t.size) if t[k] >= t0]
    step = int(POSE_BATCH_S * 1e9)
    per = max(1, int(round(POSE_BATCH_S * 400)))  # the IMU's 400 Hz
    for start in range(t0, t1 - step, step):
        times = start + np.round(np.arange(1, per + 1) * step / per).astype(np.int64)
        out.append((int(times[-1]) + int(POSE_HOLD_S * 1e9), 1, times))
    out.sort(key=lambda e: (e[0], e[1]))
    return out, truth


class Switch:
    """Which variant runs now ("now", or "before": with the code the cuts replaced), its parts and batches."""

    which = "now"
    parts: dict[str, Parts] = {}
    batches: dict[str, dict[int, int]] = {}


def install(variants: list[str]) -> list:
    """Put a dispatcher in place of every function in ``TIMED`` and ``BEFORE``: it calls the variant
    ``Switch.which``'s implementation, timed into that variant's parts. Returns what to restore."""
    before = {(owner, attr): fn for owner, attr, fn in BEFORE}
    previous = {(owner, attr): fn for owner, attr, fn in PREVIOUS}
    names = {(owner, attr): name for owner, attr, name in TIMED}
    saved = []
    for owner, attr in dict.fromkeys([(o, a) for o, a, _ in TIMED] + list(before)):
        original = getattr(owner, attr) if isinstance(owner, types.ModuleType) else owner.__dict__[attr]
        saved.append((owner, attr, original))
        impl = {"now": original, "before": before.get((owner, attr), original),
                "previous": previous.get((owner, attr), original)}
        setattr(owner, attr, _dispatcher(impl, names.get((owner, attr)), attr == "add_frames"))
    return saved


def _dispatcher(impl: dict, name: str | None, counts_batches: bool):
    @functools.wraps(impl["now"])
    def call(*args, **kwargs):
        which = Switch.which
        if counts_batches:  # add_frames(self, radar, tx_order, adcs, ...)
            sizes = Switch.batches[which]
            sizes[len(args[3])] = sizes.get(len(args[3]), 0) + 1
        if name is None:
            return impl[which](*args, **kwargs)
        parts = Switch.parts[which]
        parts.enter()
        try:
            return impl[which](*args, **kwargs)
        finally:
            parts.leave(name)
    return call


def run_passes(rec: Recording, radars: list[str], map_config, variants: list[str], limit_frames=None,
               from_s: float = DRIVING_FROM_S) -> dict[str, Pass]:
    """Every frame (or the first ``limit_frames`` of each radar) through a fresh worker per variant, the
    variants in turn message by message, which goes first alternating (so the machine's load and the caches
    fall on them alike); the CPU of each
    variant's parts and of its whole loop (the recording's reads and the messages' encoding left out)."""
    rig = load_rig(RIG)
    saved = install(variants)
    pubs, workers = {}, {}
    try:
        for v in variants:
            Switch.which, Switch.parts[v], Switch.batches[v] = v, Parts(), {}
            pubs[v] = BusPublisher(bus_endpoint("bench-map"))
            workers[v] = StripMapWorker(StripMapWorkerConfig(rig, radars, map_config, "inproc://none", "unused.h5"),
                                        pubs[v])
            workers[v].warm_up()
            Switch.parts[v] = Parts()  # the kernels' compiling and cache loading is not the map's work per frame
            Switch.batches[v] = {}
        evs, truth = events(rec, radars, from_s)
        counters = dict.fromkeys(radars, 0)
        whole = dict.fromkeys(variants, 0.0)
        t_first, next_publish, frames = None, None, 0
        iq_cache: dict[str, tuple[int, np.ndarray]] = {}
        frame_times = {name: rec.frame_time_ns(name) for name in radars}
        publish_now = False
        for t_avail, kind, payload in evs:
            if kind == 0:
                name, k = payload
                if limit_frames is not None and counters[name] >= limit_frames:
                    continue
                start, block = iq_cache.get(name, (-1, None))
                if block is None or not start <= k < start + block.shape[0]:
                    block = rec.adc_iq(name, slice(k, k + 32))
                    iq_cache[name] = start, block = k, block
                wire = frame_message_bytes(name, counters[name], int(frame_times[name][k]), block[k - start])
                counters[name] += 1
                frames += 1
            else:
                if limit_frames is not None and all(c >= limit_frames for c in counters.values()):
                    break
                s = _sample(truth, payload)
            t_first = t_avail if t_first is None else t_first
            next_publish = t_avail + int(PUBLISH_EVERY_S * 1e9) if next_publish is None else next_publish
            publish_now = t_avail >= next_publish
            if publish_now:
                next_publish += int(PUBLISH_EVERY_S * 1e9)
            # first one variant, then the other: the first to touch a new frame pays for bringing it into the caches
            for v in variants if frames % 2 else variants[::-1]:
                Switch.which = v
                worker, parts = workers[v], Switch.parts[v]
                c0 = time.process_time()
                if kind == 0:
                    parts.enter()
                    message = decode(receive(wire))
                    parts.leave("bus: decode (msgpack header, array views, typed message)")
                else:
                    message = PoseBatch(payload, s.position_m, s.orientation_xyzw, s.velocity_mps)
                worker.handle(message, live=True)
                worker._image_ready(budget_s=10.0)  # what step() does, without its wall-clock publishing
                if publish_now:
                    worker._publish_tiles()
                whole[v] += time.process_time() - c0
        sensor_s = (t_avail - t_first) * 1e-9
    finally:
        for owner, attr, fn in saved:
            setattr(owner, attr, fn)
        for pub in pubs.values():
            pub.close()
        Switch.which = "now"
    return {v: Pass(dict(Switch.parts[v].s), whole[v], frames, sensor_s, dataclasses.asdict(workers[v].status),
                    dict(sorted(Switch.batches[v].items()))) for v in variants}


# -- the code the cuts replaced, kept here to measure them against it in the same process ---------------
def _footprints_before(self, centres, looks):
    """StripMap._footprints before 'footprint_masks': one numpy mask per tile, each tile's pixel centres
    from its own tile_points call."""
    cfg = self.config
    touched, masks, xs, ys = [], [], [], []
    room = cfg.max_tiles - len(self.tiles)
    refused = 0
    for key in self.footprint_tiles(centres, looks):
        x, y = self.tile_points(key)
        if len(centres) == 1:
            mask = self.footprint_mask(x[None, :], y[:, None], centres[0], looks[0])[None]
        else:
            mask = self.footprint_mask(x[None, :], y[:, None], centres, looks)
        if not mask.any():
            continue
        if key not in self.tiles:
            if room <= 0:
                refused += 1
                continue
            room -= 1
        touched.append(key)
        masks.append(mask)
        xs.append(x)
        ys.append(y)
    self.tiles_refused += refused
    n = cfg.tile_px
    return stripmap_footprint.TilesTaken(touched, np.array(masks).reshape(-1, len(centres), n, n),
                                         np.array(xs).reshape(-1, n), np.array(ys).reshape(-1, n), refused)


def _presum_before(adc, tx_order, n_tx, presum):
    """presum_chirps before its kernel, for I/Q pairs (TXs in turn: a reshape and numpy's sum)."""
    tx_order = np.asarray(tx_order)
    groups, tx_index = [], []
    for tx in range(n_tx):
        k = np.flatnonzero(tx_order == tx)
        n = k.size // presum * presum
        groups.append(k[:n].reshape(-1, presum))
        tx_index.append(np.full(n // presum, tx))
    groups, tx_index = np.concatenate(groups), np.concatenate(tx_index)
    g = tx_order.size // n_tx // presum
    sums = adc[:g * presum * n_tx].reshape(g, presum, n_tx, *adc.shape[1:]).sum(axis=1, dtype=np.float32)
    sums = sums.swapaxes(0, 1).reshape(n_tx * g, *adc.shape[1:])
    return np.ascontiguousarray(sums).view(np.complex64)[..., 0], groups, tx_index


def _polar_masked_before(self, radar, samples, tx_m, rx_m, look_xy, taken):
    """A frame's beams read at the list of its pixels, as before ``beams_at_masked`` (the tiles' pixel
    centres from tile_points again)."""
    pts = []
    for key, mask in zip(taken.keys, taken.masks):
        x, y = self.tile_points(key)
        iy, ix = np.nonzero(mask[0])
        pts.append(np.stack([x[ix], y[iy], np.full(iy.size, self.config.z_m)], axis=1))
    return self._polar_takers(radar, samples, tx_m, rx_m, look_xy[None], np.concatenate(pts), None, samples.shape[0])


def _velocity_before(self, time_ns):
    """The moving check's velocity as before ``SampledTrajectory.velocity``: a whole sample's."""
    return self.sample(time_ns).velocity_mps


def _add_to_tiles_before(self, touched, where, values):
    """StripMap._add_to_tiles before its kernel: numpy's masked addition per tile."""
    start = 0
    for key, (pixels, m) in zip(touched, where):
        tile = self._tile(key)
        for v in values:
            tile[pixels] += v[start:start + m]
        start += m


def _trajectory_before(self):
    """StripMapWorker._trajectory before its window: every pose held."""
    t = np.concatenate([b.time_ns for b in self.poses])
    if t.size < 2:
        return None
    return SampledTrajectory(t, np.concatenate([b.position_m for b in self.poses]),
                             np.concatenate([b.orientation_xyzw for b in self.poses]),
                             np.concatenate([b.velocity_mps for b in self.poses]), source="rio")


def _footprints_previous(self, centres, looks):
    """StripMap._footprints at 7ca2ad5: footprint_masks, with a tile_points call per tile (the pixel centres
    made again by _polar_masked_previous)."""
    cfg = self.config
    n = cfg.tile_px
    touched, masks = [], []
    room = cfg.max_tiles - len(self.tiles)
    refused = 0
    keys = self.footprint_tiles(centres, looks)
    if not keys:
        return stripmap_footprint.TilesTaken([], np.zeros((0, len(centres), n, n), bool), None, None, 0)
    xy = [self.tile_points(key) for key in keys]
    all_masks = stripmap_map.footprint_masks(cfg, np.array([p[0] for p in xy]), np.array([p[1] for p in xy]), centres,
                                             looks)
    kept = []
    for i, (key, mask) in enumerate(zip(keys, all_masks)):
        if not mask.any():
            continue
        if key not in self.tiles:
            if room <= 0:
                refused += 1
                continue
            room -= 1
        touched.append(key)
        masks.append(mask)
        kept.append(i)
    self.tiles_refused += refused
    # stacked here rather than in _polar_masked (np.stack of the tiles' masks), as then: one copy either way;
    # the pixel centres for the batched path's pixel lists (a tile_points call per tile then)
    return stripmap_footprint.TilesTaken(touched, np.array(masks).reshape(-1, len(centres), n, n),
                                         np.array([xy[i][0] for i in kept]), np.array([xy[i][1] for i in kept]), refused)


def _polar_masked_previous(self, radar, samples, tx_m, rx_m, look_xy, taken):
    """StripMap._polar_masked at 7ca2ad5: the tiles' pixel centres from tile_points again."""
    wf, cfg = radar.waveform, self.config
    xy = [self.tile_points(key) for key in taken.keys]
    x, y = np.array([p[0] for p in xy]), np.array([p[1] for p in xy])
    masks = taken.masks[:, 0]
    centre, axis, _ = stripmap_map.frame_axes(tx_m, rx_m, look_xy)
    extent = stripmap_map.masked_extent(centre, axis, x, y, cfg.z_m, masks)
    beams = stripmap_map.frame_beams_over(samples, tx_m, rx_m, extent, cfg.z_m, wf.f0_hz, wf.frequency_step_hz,
                                          cfg.window, cfg.oversample, look_xy)
    return stripmap_map.beams_at_masked(beams, x, y, cfg.z_m, masks)


#: The code before this round's cuts alone (issue 34 item 5: the trajectory window, the tiles' pixel centres
#: once a frame, the tile updates' kernel), the commit the docs' figures had been measured on (7ca2ad5); the
#: glue in add_frames between them is today's.
PREVIOUS = [(StripMapWorker, "_trajectory", _trajectory_before),
            (stripmap_map.StripMap, "_add_to_tiles", _add_to_tiles_before),
            (stripmap_map.StripMap, "_footprints", _footprints_previous),
            (stripmap_map.StripMap, "_polar_masked", _polar_masked_previous)]


BEFORE = [(stripmap_map.StripMap, "_footprints", _footprints_before),
          (StripMapWorker, "_trajectory", _trajectory_before),
          (stripmap_map.StripMap, "_add_to_tiles", _add_to_tiles_before),
          (SampledTrajectory, "velocity", _velocity_before),
          (stripmap_map.StripMap, "_polar_masked", _polar_masked_before),
          (stripmap_map, "presum_chirps", _presum_before)]


def summary(p: Pass, frames_per_s: float) -> dict:
    per_frame_ms = {k: 1e3 * v / p.frames for k, v in sorted(p.parts.items(), key=lambda kv: -kv[1])}
    attributed = sum(p.parts.values())
    return {
        "frames": p.frames, "sensor_s": p.sensor_s, "frames_per_s": p.frames / p.sensor_s,
        "cpu_ms_per_frame": 1e3 * p.whole_cpu_s / p.frames,
        "parts_cpu_ms_per_frame": per_frame_ms,
        "unattributed_cpu_ms_per_frame": 1e3 * (p.whole_cpu_s - attributed) / p.frames,
        # CPU seconds per second of sensor time: the share of one core the map needs at 1x
        "core_fraction_at_1x": p.whole_cpu_s / p.sensor_s,
        "core_fraction_at_1x_from_frames": 1e-3 * frames_per_s * 1e3 * p.whole_cpu_s / p.frames,
        "batch_sizes": p.batch_sizes,
        "worker_status": {k: p.status[k] for k in ("frames_imaged", "frames_standing_still", "frames_presummed_more",
                                                   "frames_rx_summed", "frames_batched", "frames_thinned",
                                                   "frames_dropped_behind", "tiles")},
    }


def main(argv: list[str]) -> int:
    import numba

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=12.0,
                    help="of the soak's lap simulated (default 12: standing, the first straight, half a turn)")
    ap.add_argument("--repeats", type=int, default=2, help="passes over the lap; the one of least CPU is kept")
    ap.add_argument("--work", help="folder for the simulated scene, kept for later runs (default: a new temporary one)")
    ap.add_argument("--refocus-frames", type=int, default=30,
                    help="frames of each radar imaged with --map-refocus pga, for its cost apart (0: not measured)")
    args = ap.parse_args(argv)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    numba.set_num_threads(1)  # the worker's kernel threads (--map-threads 1)
    rig = load_rig(RIG)
    map_config = pipeline.resolve_map_config(types.SimpleNamespace(rig=rig), MAP, RADARS, MAX_SPEED_MPS, None)
    frames_per_s = sum(1.0 / rig.radar(n).waveform.frame_interval_s for n in RADARS)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="sarbot-bench-capacity-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"simulating {args.seconds:g} s of the soak's lap, four radars ...", flush=True)
    t0 = time.monotonic()
    path = simulate(args.seconds, work)
    print(f"  {time.monotonic() - t0:.0f} s", flush=True)
    load_before = os.getloadavg()
    out = {"scene": "soak_loop", "seconds": args.seconds, "radars": RADARS, "presum": map_config.presum,
           "algorithm": map_config.algorithm, "aperture_m": map_config.aperture_m, "pixel_m": map_config.pixel_m,
           "range_m": [map_config.range_min_m, map_config.range_max_m], "pose_batch_s": POSE_BATCH_S,
           "pose_hold_s": POSE_HOLD_S, "publish_every_s": PUBLISH_EVERY_S, "radar_frames_per_s_at_1x": frames_per_s}
    with Recording(path) as rec:
        passes = {"before": [], "previous": [], "now": []}
        loads = []  # CPU time grows with the machine's load too (caches shared with others' work)
        for r in range(args.repeats):
            loads.append(os.getloadavg()[0])
            # the code before the cuts, before this round's and now, message by message in turn: the machine's
            # load falls on all alike
            for which, p in run_passes(rec, RADARS, map_config, list(passes)).items():
                passes[which].append(p)
                print(f"pass {r}, {which}: {1e3 * p.whole_cpu_s / p.frames:.2f} ms CPU a frame, "
                      f"{p.whole_cpu_s / p.sensor_s:.3f} of a core at 1x; batches {p.batch_sizes}", flush=True)
        best = {w: min(ps, key=lambda p: p.whole_cpu_s / p.frames) for w, ps in passes.items()}
        out["polar"] = summary(best["now"], frames_per_s)
        out["polar_before_cuts"] = summary(best["before"], frames_per_s)
        out["polar_before_this_round"] = summary(best["previous"], frames_per_s)
        out["passes_cpu_ms_per_frame"] = {w: [1e3 * p.whole_cpu_s / p.frames for p in ps] for w, ps in passes.items()}
        out["load_average_1min_at_each_pass"] = loads
        out["before_over_now_each_pass"] = [b.whole_cpu_s / n.whole_cpu_s for b, n in zip(passes["before"], passes["now"])]
        out["before_this_round_over_now_each_pass"] = [b.whole_cpu_s / n.whole_cpu_s
                                                       for b, n in zip(passes["previous"], passes["now"])]
        out["this_round"] = ("issue 34 item 5: the trajectory window, the tiles' pixel centres once a frame, the tile "
                             "updates' kernel; 'polar_before_this_round' is the code before them alone (7ca2ad5), "
                             "with today's glue in add_frames")
        out["cuts"] = {"footprint masks": "one numba kernel for every tile (imaging.stripmap.footprint.footprint_masks)",
                       "presum": "I/Q pairs summed by a numba kernel (imaging.stripmap.presum._sum_pairs)",
                       "moving check": "the trajectory's velocity alone (SampledTrajectory.velocity), not a whole sample",
                       "pixels": "one frame's beams read at its tiles' masked pixels, without a list of them "
                                 "(imaging.stripmap.polar.beams_at_masked)",
                       "trajectory window": "the worker's trajectory from the pose batch before the oldest queued "
                                            "frame's on, not every pose held (StripMapWorker._trajectory)",
                       "tile points": "the tiles' pixel centres once a frame, in one operation "
                                      "(StripMap._footprints' TilesTaken), not a tile_points call per tile twice",
                       "tile updates": "a frame's values added at each tile's masked pixels by a numba kernel "
                                       "(StripMap._add_to_tiles), not numpy's masked +="}
        print("ratio before/now each pass:", [round(v, 3) for v in out["before_over_now_each_pass"]])
        print("ratio before this round/now each pass:", [round(v, 3) for v in out["before_this_round_over_now_each_pass"]])
        for k, v in out["polar"]["parts_cpu_ms_per_frame"].items():
            print(f"  {v:7.3f} ms  {out['polar_before_this_round']['parts_cpu_ms_per_frame'].get(k, 0.0):7.3f} previous  "
                  f"{out['polar_before_cuts']['parts_cpu_ms_per_frame'].get(k, 0.0):7.3f} before  {k}")
        if args.refocus_frames:
            refocus = dataclasses.replace(map_config, algorithm="direct", refocus="pga")
            p = run_passes(rec, RADARS, refocus, ["now"], limit_frames=args.refocus_frames)["now"]
            out["refocus_pga_direct"] = summary(p, frames_per_s)
            print(f"refocusing (pga): {1e3 * p.whole_cpu_s / p.frames:.1f} ms CPU a frame", flush=True)
    out["commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                   text=True).stdout.strip()
    out.update(load_average_before=list(load_before), load_average_after=list(os.getloadavg()),
               cpu_count=os.cpu_count(), numba_threads=1)
    write_results("stripmap_capacity", out, started_load=started_load, indent=1)
    print(f"wrote {RESULTS / 'stripmap_capacity.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
