"""The strip-map worker: radar frames, and poses from the odometry worker -> ``imaging.stripmap.StripMap``.

A frame is imaged once the poses cover it. Changed tiles go out as ``map/tile``, the state as
``map/status`` (with the lag behind real time); at the end the map is written in the image schema, with
a PNG beside it.
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import logging
import time
import typing
from pathlib import Path

import numpy as np

from imaging.core.rig import Rig

from ..messages import MapStatus, MapTile, MapVelocityError, PoseBatch, PoseEnd, RadarFrameMessage, RadarImuBatch
from . import Worker

log = logging.getLogger(f"sarbot.{__name__}")


class QueuedFrame(typing.NamedTuple):
    """A radar frame waiting for the poses that place it. ``iq`` is the received message's own buffer, not a
    copy: a copy of every frame cost the catching-up map a seventh of its time (page faults on this VM)."""

    radar: str
    iq: np.ndarray  # int16 I/Q pairs [chirps, rx, samples, 2]
    frame_time_ns: int
    receive_ns: int  # when the frame arrived: the map's lag is measured from it

@dataclasses.dataclass
class RefocusJob:
    """The tiles one imaging call finished (``FrameFootprint.finished``), refocused a tile at a time and read
    together: ``keys`` those left, ``changed`` those whose image changed so far, ``named_s`` when they were
    finished (monotonic)."""

    named_s: float
    keys: list
    changed: list = dataclasses.field(default_factory=list)

    def __post_init__(self) -> None:
        self.tiles = len(self.keys)


#: How far back from the newest pose the worker keeps poses at least; further back as long as a queued frame
#: needs them (a frame imaged on poses no longer held would be placed at the first pose held: smeared).
POSE_WINDOW_NS = 5_000_000_000
#: Longest a live imaging pass runs before the worker takes its messages again.
STEP_BUDGET_S = 0.25
#: Refocusing (``refocus``): the finished tiles a frame names are one job, refocused after the step's imaging,
#: a tile at a time, one tile a step at least and more while within this time. Refocused inside the imaging call, as the map
#: did, a tile's autofocus held the frames behind it: with OpenBLAS's own threads (below) a target's tile took
#: 5-12 s of CPU at load 9-15 and the two-radar map ended 10-21 s behind (benchmarks/refocus_threads.py).
REFOCUS_STEP_BUDGET_S = 0.1
#: The most the last imaging and refocus passes after the drivers stop may take (``StripMapWorker.finish_max_s``):
#: with up to 10 s of draining before it and WRITE_RESERVE_S for the map after, it fits in the daemon's 60 s
#: (``worker_stop_timeout_s``); a shorter timeout cuts both budgets to fit (``workers.stop_budgets``). Frames
#: still queued then are dropped (``frames_dropped_behind``), tiles still awaiting their refocus stay as imaged
#: (``tiles_awaiting_refocus``), both said in a warning. A single imaging call can outlast it (a numba call
#: cannot be interrupted): then the daemon's SIGTERM hurries the worker (``stop_cut_short``).
FINISH_BUDGET_S = 30.0
#: Kept for writing the map (HDF5 and PNG) within the daemon's stop timeout, s: an allowance, not a measurement.
WRITE_RESERVE_S = 5.0
#: Behind by more than CATCH_UP_START_S of sensor time, the worker sums twice the chirps per profile, four
#: times CATCH_UP_STEP_S later, and so on (up to all of a TX's chirps in a frame): fewer profiles, a coarser
#: map, before it drops a frame (at ``max_queue_s``). The backlog counts the frames waiting for the
#: odometry's poses too: on a shared machine an odometry behind is one short of CPU, and a coarser map leaves
#: it more. In the four-radar soak the map lagged 4-5 s when coarsening began at 4 s, 1.2-1.3 s (median) when
#: it began at 1 s, 0.75-0.86 s from 0.5 s. The start was 0.5 s while the odometry held its poses back 0.2 s
#: behind the radars (a wait of 0.24 s, median); without that hold-back (0.04 s) the same start only lets the
#: queue of frames to image grow 0.2 s longer at the same pre-summing, so it starts 0.2 s sooner. Steps of
#: 0.15 s (0.25 s before the steps below) reach all of a TX's chirps 0.75 s behind and the last step 1.2 s
#: behind: in five-minute soaks the highest lag was 2.0 s against 4.4 s with 0.25 s steps.
CATCH_UP_START_S = 0.3
CATCH_UP_STEP_S = 0.15
#: The catch-up's last steps, once a TX's chirps are all summed into one profile: each TX's RX channels
#: summed into one (``StripMap.add_frames(sum_rx=True)``: 1.45x less CPU a frame, the map's error against every
#: frame at the default pre-summing -8.8 dB against -9.0 dB without; benchmarks/stripmap_thinning.py), then
#: one frame of a radar in 2 imaged, then one in 4 (at most MAX_THINNING), each weighted by that factor so the
#: map keeps its scale. Thinning is a coarser slow-time sampling of the same aperture, and it shows: the
#: frames 2 cm apart no longer overlap their 3 cm virtual array, so grating lobes rise (peak side lobe -4.6 dB
#: at 1 in 2, -1.5 dB at 1 in 4, against -20 dB), counted (``frames_thinned``), but the map keeps up: on a
#: machine so short of CPU that the niced map gets a tenth of a core for tens of seconds (the four-radar soak,
#: whose emulated hardware takes half a core of the same two), it otherwise fell 5-10 s behind.
MAX_THINNING = 4
#: The most steps the ladder counts (2^32 times the pre-summing is past any waveform's chirps).
MAX_LADDER_STEPS = 32


def is_thinning(n: int) -> bool:
    """Whether ``n`` can be a thinning factor: 1, 2, 4, ... (the ladder doubles it)."""
    return n >= 1 and n & (n - 1) == 0
#: The most queued frames of one radar imaged in one call (``StripMap.add_frames``: the same map, less work
#: per frame). Only frames already queued and covered by poses go together, so batching adds no lag. It pays
#: where the map is far behind: pre-summing all of a TX's chirps, 8 frames together cost 1.5x less CPU each
#: than one at a time (4: 1.4x); at the default pre-summing the kernel dominates and it gains nothing
#: (benchmarks/stripmap.py).
MAX_BATCH_FRAMES = 8


@dataclasses.dataclass
class StripMapWorkerConfig:
    """``radars`` None: all of the rig's. ``map`` is the ``imaging.stripmap.StripMapConfig``. Frames wait
    for poses at most ``max_queue_s`` (of sensor time) before the oldest are dropped, counted; before that,
    a backlog is imaged with more pre-summing (``catch_up_start_s``, ``catch_up_step_s``), then ("polar" or "direct", no
    refocusing) with each TX's RX channels summed, then with only one frame of a radar in 2, 4 (up to
    ``max_thinning``; 1: never), counted too.
    Frames of one radar already queued and covered by poses are imaged together, up to ``max_batch_frames``
    (with "polar" or "direct" and no refocusing; the map is the same).
    ``threads``: the backprojection kernel's threads, and BLAS's (numpy's and scipy's: the refocus). One by default: beside the drivers, the recorder and
    the odometry a second thread mostly waits for a core, and the same frames cost more CPU with two (14.8
    against 9.4 ms per frame on this two-core machine, benchmarks/stripmap.py); more only where the map has
    cores to itself."""

    rig: Rig
    radars: list[str] | None
    map: object
    pose_endpoint: str
    map_path: str
    max_queue_s: float = 10.0
    catch_up_start_s: float = CATCH_UP_START_S
    catch_up_step_s: float = CATCH_UP_STEP_S
    threads: int = 1
    max_batch_frames: int = MAX_BATCH_FRAMES
    max_thinning: int = MAX_THINNING

    def __post_init__(self) -> None:
        from imaging.core.config import require
        from imaging.stripmap import MAX_BATCH_FRAMES as most

        require(self.threads >= 1, "threads", f"must be at least 1, got {self.threads}")
        require(1 <= self.max_batch_frames <= most, "max_batch_frames",
                f"must be 1 to {most}, got {self.max_batch_frames}")
        require(is_thinning(self.max_thinning), "max_thinning",
                f"must be 1, 2, 4, ... (one frame in that many imaged at most), got {self.max_thinning}")


class StripMapWorker(Worker):
    # It waits for the odometry's last poses (PoseEnd), which come after the drivers stop.
    drain_quiet_s = 10.0
    drain_max_s = 10.0
    finish_max_s = FINISH_BUDGET_S
    write_reserve_s = WRITE_RESERVE_S

    def __init__(self, config: StripMapWorkerConfig, pub):
        from imaging.stripmap import StripMap

        self.config = config
        self.pub = pub
        rig = config.rig
        use = set(config.radars or rig.radar_names)
        # Only the radars it images: each stream is 14 MB/s the process would otherwise receive for nothing.
        self.topics = [PoseBatch.TOPIC, *[RadarFrameMessage.topic_of(n) for n in sorted(use)]]
        self.endpoints = [config.pose_endpoint]
        self.radars = {r.name: r for r in rig.radars if r.name in use}
        if config.map.refocus_imu_aided:  # the IMUs on the mapped radars' own mounts
            self.topics += [RadarImuBatch.topic_of(n) for n, r in sorted(self.radars.items()) if r.imu is not None]
        self.orders = {name: np.asarray(r.waveform.tdm_tx_order()) for name, r in self.radars.items()}
        self.frame_ns = {name: r.waveform.frame_duration_ns for name, r in self.radars.items()}
        self.map = StripMap(config.map, refocus_later=True)
        #: finished tiles to refocus, a job per imaging call that finished any
        self.refocus_jobs: collections.deque[RefocusJob] = collections.deque()
        # A block ("ffbp") is already a batch, and refocusing keeps every frame's own group images.
        direct = config.map.algorithm != "ffbp" and not config.map.refocuses
        self.batch_frames = config.max_batch_frames if direct else 1
        # refocusing keeps every channel's group images, and an "ffbp" block one layout of channels
        self.sums_rx = {name: direct and r.waveform.n_rx > 1 for name, r in self.radars.items()}
        self.status = MapStatus()
        self.poses: collections.deque[PoseBatch] = collections.deque()
        self.frames: collections.deque[QueuedFrame] = collections.deque()
        #: radar -> receive times of its frames in the map's unfinished block ("ffbp"), for the lag
        self.in_block: dict[str, collections.deque] = {name: collections.deque() for name in self.radars}
        #: radar -> its frames taken off the queue while thinning, to keep one in every k
        self.thinning_count = dict.fromkeys(self.radars, 0)
        self.changed: set = set()
        self.last_publish = time.monotonic()

    def warm_up(self) -> None:
        """Image one noise frame of every radar into a throwaway map along a made-up straight drive: the
        range compression and backprojection kernels compile for the live shapes and dtypes. First, the
        worker's process takes the kernel threads it is configured for."""
        import numba
        from threadpoolctl import threadpool_limits

        from imaging.core.trajectory import SampledTrajectory, StraightLine
        from imaging.stripmap import StripMap

        numba.set_num_threads(min(self.config.threads, numba.config.NUMBA_NUM_THREADS))
        if self.config.map.refocuses:
            import imaging.autofocus  # noqa: F401 - scipy's optimizers and its OpenBLAS loaded before the limit below
            import rio.map_feedback  # noqa: F401
            import scipy.ndimage  # noqa: F401
        # numpy's and scipy's OpenBLAS run a thread per core of their own. The refocus's entropy gradient is
        # a product of small matrices per 256 pixels, and on a loaded machine (other processes on both cores)
        # those threads wait for each other at every call: 0.22-0.36 s of CPU for a target's tile on one
        # thread, 5.1-12.5 s on two at load 9-15, the same estimates (benchmarks/refocus_threads.py). The map
        # uses ``threads`` cores for BLAS as for its kernels.
        threadpool_limits(self.config.threads, user_api="blas")
        rng = np.random.default_rng(0)
        t0 = 1_000_000_000
        drive = StraightLine(speed_mps=0.4, t0_ns=t0)
        traj = SampledTrajectory.from_trajectory(drive, t0 + np.arange(0, 2_000_000_000, 10_000_000, dtype=np.int64))
        presum = self.config.map.presum
        for name, radar in self.radars.items():
            wf = radar.waveform
            shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)  # I/Q pairs, as frames arrive
            noise = rng.integers(-512, 512, shape, dtype=np.int16)
            noise.flags.writeable = False  # as a frame off the bus is: numba compiles read-only arrays apart
            # A worker behind images queued frames together (add_frames), whose path compiles apart: warmed too,
            # or a cold cache's first batch stalls the live map for seconds.
            later = [t0 + 600_000_000, t0 + 600_000_000 + int(wf.frame_interval_s * 1e9)]
            # Every step of the catch-up ladder: past POLAR_MIN_PROFILES profiles a frame the map images by
            # direct backprojection instead of by beams, a kernel of its own. Left to the first frames behind, a
            # cold cache compiled it live (60 s of CPU on the AMD VM, 75 s at nice 10): the map fell 75 s behind
            # and was killed at the stop (the official CI's demo, 2026-11-26).
            for factor, sum_rx in self.catch_up_paths(name):
                scratch = StripMap(self.config.map)
                scratch.add_frames(radar, self.orders[name], [noise], [t0 + 500_000_000], traj,
                                   presum=presum * factor, sum_rx=sum_rx)
                scratch.add_frames(radar, self.orders[name], [noise, noise], later, traj, presum=presum * factor,
                                   sum_rx=sum_rx)
                scratch.flush()  # "ffbp": a one-frame block compiles the factorized kernels

    def _add_poses(self, batch: PoseBatch) -> None:
        """Keep poses in time order; a batch that repeats times already held keeps only its newer ones."""
        t = batch.time_ns
        keep = t > self.poses[-1].time_ns[-1] if self.poses else np.ones(t.size, bool)
        if keep.any():
            self.poses.append(PoseBatch(*(np.array(a[keep]) for a in (t, batch.position_m, batch.orientation_xyzw,
                                                                       batch.velocity_mps))))

    def handle(self, message, live: bool) -> None:
        """A pose batch or a radar frame. Live, the pose window and the frame queue are kept bounded; when
        draining at the end, everything is kept for the last imaging pass."""
        frames, status = self.frames, self.status
        if isinstance(message, RadarImuBatch):
            if message.radar in self.radars:
                self.map.add_radar_imu(message.radar, message.batch.time_ns, message.batch.accel_mps2)
            return
        if isinstance(message, PoseBatch):
            self._add_poses(message)
            if live:
                self._forget_poses()
            return
        if not isinstance(message, RadarFrameMessage) or message.radar not in self.radars:
            return
        f = message.frame
        if not f.valid:
            status.frames_skipped_invalid += 1
            return
        frames.append(QueuedFrame(message.radar, f.iq, f.frame_time_ns, f.receive_ns))
        # Never fall more than max_queue_s behind: the oldest frames go (counted).
        while live and self._queued_s() > self.config.max_queue_s:
            frames.popleft()
            status.frames_dropped_behind += 1

    def _queued_s(self) -> float:
        """Sensor time from the oldest queued frame to the newest, s (0 with none queued)."""
        frames = self.frames
        return (frames[-1].frame_time_ns - frames[0].frame_time_ns) * 1e-9 if frames else 0.0

    def lost_on_bus(self, missed: dict[str, int]) -> None:
        self.status.frames_lost_on_bus = sum(missed.get(RadarFrameMessage.topic_of(n), 0) for n in self.radars)

    def _oldest_frame_ns(self) -> int:
        """The earliest queued frame's start, ns: not the first queued, as the radars' frames arrive interleaved,
        not in time order."""
        return min(int(f.frame_time_ns) for f in self.frames)

    def _forget_poses(self) -> None:
        """Drop the pose batches neither the last POSE_WINDOW_NS nor any queued frame needs."""
        poses = self.poses
        keep_from = int(poses[-1].time_ns[-1]) - POSE_WINDOW_NS
        if self.frames:
            keep_from = min(keep_from, self._oldest_frame_ns())
        while len(poses) > 2 and poses[1].time_ns[0] <= keep_from:
            poses.popleft()

    def drained(self, message) -> bool:
        return isinstance(message, PoseEnd)

    def _trajectory(self):
        """The poses the queued frames need, as a trajectory: from the pose batch before the one holding the
        oldest queued frame's start on (all of them with no frame queued). A frame is placed by the poses
        around its own chirps (linear and slerp between neighbours, the acceleration a central difference one
        pose further), so this places every queued frame as all the poses held do, to float rounding of the
        time origin (tests/test_stripmap.py). All of them (5 s live, minutes while draining), concatenated
        and set up again for every call, were a ninth of the map's CPU a frame
        (benchmarks/stripmap_capacity.py)."""
        from imaging.core.trajectory import SampledTrajectory

        poses = self.poses
        first = len(poses) - 1
        if self.frames:
            start = self._oldest_frame_ns()
            while first > 0 and int(poses[first].time_ns[0]) > start:
                first -= 1
        batches = list(itertools.islice(poses, max(first - 1, 0), None))
        if sum(b.time_ns.size for b in batches) < 2:
            return None
        return SampledTrajectory.from_batches(batches)

    def _image_ready(self, final: bool = False, budget_s: float | None = None) -> None:
        """Image the queued frames the poses cover, oldest first; live, for at most ``budget_s``."""
        frames, status = self.frames, self.status
        if not frames or not self.poses:
            status.waiting_for_poses_s = self._queued_s()
            return
        newest_pose = int(self.poses[-1].time_ns[-1])
        status.waiting_for_poses_s = max(0.0, (frames[-1].frame_time_ns - newest_pose) * 1e-9)
        traj = None
        until = None if budget_s is None else time.monotonic() + budget_s
        while frames and (until is None or time.monotonic() < until) and not self.hurried:
            name, t_frame = frames[0].radar, frames[0].frame_time_ns
            if not self._covered(name, t_frame, newest_pose):
                if not final:
                    return
                frames.popleft()  # never covered by the odometry: the drive ended
                status.frames_beyond_odometry += 1
                continue
            traj = traj or self._trajectory()
            if traj is None:  # a single pose so far: the frame waits for the next (at the end, finish counts it)
                return
            factor, sum_rx, thinning = (1, False, 1) if final else self.catch_up(name)
            batch = self._take_batch(name, newest_pose, self.batch_frames * thinning)
            status.thinning = thinning
            if thinning > 1:
                batch = self._thin(name, batch, thinning)
                if not batch:
                    continue
            t0, cpu = time.monotonic(), time.process_time()
            footprint = self.map.add_frames(self.radars[name], self.orders[name], [f.iq for f in batch],
                                            [f.frame_time_ns for f in batch], traj, presum=self.config.map.presum * factor,
                                            weight=float(thinning), sum_rx=sum_rx)
            status.presum_factor = factor
            if not footprint.skipped:
                moving = len(batch) - footprint.frames_standing
                status.frames_presummed_more += moving if factor > 1 else 0
                status.frames_rx_summed += moving if sum_rx else 0
                status.frames_batched += moving if len(batch) > 1 else 0
                self.in_block[name].extend(f.receive_ns for f in batch)
            self._account(name, footprint, final)
            took = time.monotonic() - t0
            status.busy_s += took
            log.debug("strip map: %s %d frame(s) imaged in %.1f ms (%.1f ms CPU; presum x%d, thinning %d), %d tile(s) "
                      "finished, lag %.2f s", name, footprint.frames_imaged, took * 1e3, (time.process_time() - cpu) * 1e3,
                      factor, thinning, len(footprint.finished), status.lag_s)

    def _covered(self, name: str, t_frame: int, newest_pose: int) -> bool:
        """Whether the poses reach to the end of radar ``name``'s frame starting at ``t_frame``."""
        return t_frame + self.frame_ns[name] <= newest_pose

    def _take_batch(self, name: str, newest_pose: int, most: int) -> list[QueuedFrame]:
        """Take the oldest queued frame (radar ``name``'s) and the next of the same radar the poses cover, up to
        ``most``, off the queue; the other radars' frames keep their places."""
        frames = self.frames
        batch = [frames.popleft()]
        if most == 1:
            return batch
        # Look no further than the next few frames of every radar: they arrive interleaved.
        horizon = min(len(frames), 2 * most * len(self.radars))
        taken = []
        for i in range(horizon):
            if frames[i].radar != name:
                continue
            if not self._covered(name, frames[i].frame_time_ns, newest_pose):
                break
            taken.append(i)
            if len(taken) + 1 == most:
                break
        for i in reversed(taken):
            batch.insert(1, frames[i])
            del frames[i]
        return batch

    def _thin(self, name: str, batch: list[QueuedFrame], thinning: int) -> list[QueuedFrame]:
        """One of every ``thinning`` frames of radar ``name`` (counting on across batches); the others are
        counted as thinned."""
        kept = [b for i, b in enumerate(batch, self.thinning_count[name]) if i % thinning == 0]
        self.thinning_count[name] += len(batch)
        self.status.frames_thinned += len(batch) - len(kept)
        return kept

    def _account(self, name: str, footprint, final: bool) -> None:
        """Count what one call into the map did. A frame is imaged when its data is in the map: at once, or
        ("ffbp") when its block is; the lag is then the block's oldest frame's."""
        status = self.status
        self.changed.update(footprint.tiles)
        self.changed.update(footprint.refocused)
        status.tiles_refocused += len(footprint.refocused)
        if footprint.refocused:
            self._publish_velocity_error(footprint.refocused)
        if footprint.finished:
            self.refocus_jobs.append(RefocusJob(time.monotonic(), list(footprint.finished)))
            status.tiles_awaiting_refocus += len(footprint.finished)
        status.frames_standing_still += footprint.frames_standing
        if self.map.frames_off_map > status.frames_off_map:
            if status.frames_off_map == 0:
                log.warning("strip map: %d tiles, its limit (max_tiles); frames needing new tiles are left out "
                            "(counted as frames_off_map)", len(self.map.tiles))
            status.frames_off_map = self.map.frames_off_map
        received = self.in_block[name]
        if footprint.frames_imaged or footprint.skipped == "map full":
            status.frames_imaged += footprint.frames_imaged
            oldest = received[0] if received else None
            received.clear()
            # the last pass after the run stops says how long shutting down took, not the lag
            if oldest is not None and footprint.frames_imaged and not final:
                status.lag_s = (time.time_ns() - oldest) * 1e-9
                status.max_lag_s = max(status.max_lag_s, status.lag_s)

    def _refocus_ready(self, budget_s: float | None) -> None:
        """Refocus the finished tiles, oldest job first, a tile at a time: one tile at least, more while within
        ``budget_s`` (None: all). A job's tiles, once all refocused, read one velocity error together
        (``map/velocity_error``)."""
        status, jobs = self.status, self.refocus_jobs
        until = None if budget_s is None else time.monotonic() + budget_s
        while jobs and not self.hurried:
            job = jobs[0]
            t0, cpu = time.monotonic(), time.process_time()
            if len(job.keys) == job.tiles:  # its first tile
                status.refocus_wait_s = t0 - job.named_s
                status.max_refocus_wait_s = max(status.max_refocus_wait_s, status.refocus_wait_s)
            key = job.keys.pop(0)
            if self.map.refocus_tiles([key]):
                job.changed.append(key)
            took = time.monotonic() - t0
            status.refocus_s += took
            status.refocus_max_s = max(status.refocus_max_s, took)
            status.tiles_awaiting_refocus -= 1
            result = self.map.refocus_results.get(key)
            # CPU beside wall time: on a loaded machine the two part, and only CPU says what a tile costs
            log.debug("strip map: tile %s refocused in %.3f s (%.3f s CPU), %s groups, %s iterations, applied %s, "
                      "finished %.2f s before", key, took, time.process_time() - cpu, getattr(result, "groups", "-"),
                      getattr(result, "iterations", "-"), getattr(result, "applied", "-"), t0 - job.named_s)
            if not job.keys:
                jobs.popleft()
                status.tiles_refocused += len(job.changed)
                self.changed.update(job.changed)
                if job.changed:
                    self._publish_velocity_error(job.changed)
            if until is not None and time.monotonic() >= until:
                return

    def counters(self) -> dict[str, int]:
        """The map's state for health, each second (``map/status`` says the same with the tiles): its lag
        and busy time in ms, the refocus's time, its longest job and how long the latest waited, in ms."""
        s = self.status
        ms = {k: round(getattr(s, k) * 1e3) for k in ("lag_s", "max_lag_s", "busy_s", "refocus_s", "refocus_max_s",
                                                      "refocus_wait_s", "max_refocus_wait_s")}
        return {"frames_imaged": s.frames_imaged, "frames_queued": len(self.frames),
                "frames_dropped_behind": s.frames_dropped_behind, "frames_thinned": s.frames_thinned,
                "tiles_refocused": s.tiles_refocused, "tiles_awaiting_refocus": s.tiles_awaiting_refocus,
                **{k[:-2] + "_ms": v for k, v in ms.items()}}

    def _publish_velocity_error(self, keys) -> None:
        """The trajectory's velocity error read off tiles refocused together (rio.map_feedback), on
        ``map/velocity_error`` for the odometry; nothing where their estimates were not applied or do not
        read as one velocity error."""
        from rio.map_feedback import velocity_error_from_tiles

        geometry, results = self.map.refocus_geometry, self.map.refocus_results
        tiles = [(results[k].track_error, geometry[k]) for k in keys if k in geometry and k in results]
        for m in velocity_error_from_tiles(tiles) if tiles else []:
            self.pub.send(MapVelocityError.of(m))

    def catch_up(self, radar: str) -> tuple[int, bool, int]:
        """How the oldest queued frame (radar ``radar``'s) is imaged: (extra pre-summing, RX channels summed,
        thinning). (1, False, 1) while the queue holds less than ``catch_up_start_s`` of sensor time; then
        pre-summing 2, doubling every ``catch_up_step_s`` more up to all of a TX's chirps; the next step sums
        the RX channels (where the map can), the steps after that thin 2, 4, ... up to ``max_thinning``."""
        cfg = self.config
        backlog_s = self._queued_s()
        if backlog_s < cfg.catch_up_start_s:
            return 1, False, 1
        steps = 1 + (int((backlog_s - cfg.catch_up_start_s) / cfg.catch_up_step_s) if cfg.catch_up_step_s > 0 else 0)
        return self._ladder_step(radar, min(steps, MAX_LADDER_STEPS))

    def catch_up_paths(self, radar: str) -> list[tuple[int, bool]]:
        """Every (extra pre-summing, RX channels summed) the catch-up ladder reaches for radar ``radar``, from
        (1, False): each may image through kernels of its own (``warm_up`` compiles them all)."""
        paths = []
        for steps in range(MAX_LADDER_STEPS + 1):
            factor, sum_rx, _ = self._ladder_step(radar, steps)
            if (factor, sum_rx) not in paths:
                paths.append((factor, sum_rx))
        return paths

    def _ladder_step(self, radar: str, steps: int) -> tuple[int, bool, int]:
        """(extra pre-summing, RX channels summed, thinning) ``steps`` steps up the ladder (0: none)."""
        if steps == 0:
            return 1, False, 1
        cfg = self.config
        wf = self.radars[radar].waveform
        most = max(1, wf.chirps_per_frame // wf.n_tx // cfg.map.presum)
        factor = min(2 ** steps, most)
        beyond = steps - (most - 1).bit_length()  # steps past the one that first sums all of a TX's chirps
        sum_rx = self.sums_rx[radar] and beyond >= 1
        return factor, sum_rx, min(2 ** max(beyond - self.sums_rx[radar], 0), cfg.max_thinning)

    def _publish_tiles(self) -> None:
        cfg = self.config.map
        for key in sorted(self.changed):
            self.pub.send(MapTile(key, cfg.pixel_m, cfg.tile_px, self.map.tiles[key]))
        self.changed.clear()
        self.status.tiles = len(self.map.tiles)
        self.status.tiles_without_radar_imu = self.map.tiles_without_radar_imu
        self.status.time_ns = time.time_ns()
        self.pub.send(self.status)
        self.last_publish = time.monotonic()

    def step(self) -> None:
        self._image_ready(budget_s=STEP_BUDGET_S)
        self._refocus_ready(budget_s=REFOCUS_STEP_BUDGET_S)
        if time.monotonic() - self.last_publish > 0.5:
            self._publish_tiles()

    def finish(self) -> None:
        """The last imaging and refocus passes, within ``finish_max_s``; the last tiles and status out.
        Hurried (SIGTERM: the daemon's stop timeout passed), the queued frames are dropped and no tile is
        refocused (both counted, ``stop_cut_short`` set); only the FFBP block in progress is still imaged."""
        status = self.status
        budget_s = self.finish_max_s
        until = time.monotonic() + budget_s
        self._image_ready(final=True, budget_s=budget_s)
        if self.hurried or (time.monotonic() >= until and self.frames):
            left = len(self.frames)
            if self.hurried:
                log.warning("strip map: hurried at the stop; %d queued frame(s) dropped", left)
            else:
                log.warning("strip map: %d frame(s) still queued %.0f s after the stop; dropped", left, budget_s)
            status.frames_dropped_behind += left
            self.frames.clear()
        # Whatever is left had no poses at all (an odometry that never started): counted, so every frame
        # received is accounted for in map/status.
        status.frames_beyond_odometry += len(self.frames)
        self.frames.clear()
        ended = self.map.flush()
        self.changed.update(ended.tiles)
        status.frames_imaged += ended.frames_imaged
        if self.config.map.refocuses:
            while self.refocus_jobs and time.monotonic() < until and not self.hurried:
                self._refocus_ready(budget_s=0.0)
            if time.monotonic() < until and not self.hurried:
                refocused = self.map.refocus_pending()
                self.changed.update(refocused)
                status.tiles_refocused += len(refocused)
            else:
                status.tiles_awaiting_refocus = self.map.tiles_to_refocus
                log.warning("strip map: %d tile(s) not refocused %s; left as imaged", status.tiles_awaiting_refocus,
                            "(hurried at the stop)" if self.hurried else f"{budget_s:.0f} s after the stop")
        status.stop_cut_short = int(self.hurried)
        self._publish_tiles()

    def write_products(self) -> None:
        from imaging.io.image_file import write_image
        from imaging.plot import save_image_png

        if not self.map.tiles:
            return
        # Hurried before finish ran (SIGTERM while warming up, an error): the file says it was cut short too.
        self.status.stop_cut_short = max(self.status.stop_cut_short, int(self.hurried))
        status = {k: v for k, v in dataclasses.asdict(self.status).items() if k not in ("tiles", "time_ns")}
        img = self.map.to_image({"radars": ",".join(sorted(self.radars)), "trajectory_source": "rio",
                                 "wavelength_m": float(np.mean([r.waveform.wavelength_m for r in self.radars.values()])),
                                 **status})
        if self.map.mosaic_tiles_left_out:
            log.warning("strip map: its tiles span more than the mosaic's limit; the file holds the %d x %d m around "
                        "them, %d tile(s) left out (an odometry gone astray?)",
                        round(float(np.ptp(img.x_m))), round(float(np.ptp(img.y_m))), self.map.mosaic_tiles_left_out)
        path = self.config.map_path
        write_image(path, img)
        save_image_png(Path(path).with_suffix(".png"), img.image, img.x_m, img.y_m,
                       title=f"strip map, {self.status.frames_imaged} frames, aperture {self.config.map.aperture_m} m")
        log.info("strip map: %s; wrote %s", status, path)
