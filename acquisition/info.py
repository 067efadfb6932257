"""``sarbot info FILE``: what a recording, trajectory or image holds, as text or JSON.

For a recording: per radar the waveform, frames, rate, invalid frames, counter gaps and duration; the
IMU's rate, sample count, counter gaps and clock drift; CAN frames, triggers, events by level, truth.
For a trajectory: source, poses, rate, duration, path length. For an image: size, pixel, extent,
frames and how it was made. The kind is told by the file's ``schema`` attribute.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imaging.core.errors import FileFormatError, SarbotError


#: ``open_state``: the file was closed by its writer.
CLOSED = "closed"
#: ``open_state``: a writer holds the file now (a recorder running): read as SWMR readers do.
BEING_WRITTEN = "being written"
#: ``open_state``: the writer's SWMR flag is still set but nobody holds the file: a recorder killed (SIGKILL,
#: power cut). Readable up to its last flush, as export and replay read it.
NOT_CLOSED_CLEANLY = "not closed cleanly"


def open_state(path: str | Path) -> str:
    """How the HDF5 file at ``path`` was left: CLOSED, BEING_WRITTEN or NOT_CLOSED_CLEANLY; FileFormatError
    when it cannot be opened at all (missing, not HDF5, damaged)."""
    path = Path(path)
    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    try:
        with h5py.File(path, "r"):
            return CLOSED
    except OSError as exc:
        text = str(exc).lower()
    if "unable to lock file" in text:  # HDF5's file lock: a live writer
        return BEING_WRITTEN
    if "already open for" in text:  # the SWMR-write flag, and no lock: its writer is gone
        return NOT_CLOSED_CLEANLY
    raise FileFormatError(f"{path}: not a readable HDF5 file, damaged or cut short") from None


def _open(path: Path, state: str) -> h5py.File:
    try:
        return h5py.File(path, "r", **({} if state == CLOSED else {"swmr": True}))
    except OSError as exc:
        raise FileFormatError(f"{path}: not a readable HDF5 file, damaged or cut short ({exc})") from None


def file_kind(path: str | Path) -> str:
    """``recording``, ``trajectory`` or ``image``, from the schema attribute; FileFormatError otherwise."""
    from imaging.io import image_file, recording, trajectory_file

    path = Path(path)
    state = open_state(path)
    try:
        with _open(path, state) as f:
            schema = f.attrs.get("schema")
    except (KeyError, RuntimeError, ValueError) as exc:  # damaged metadata under the superblock
        raise FileFormatError(f"{path}: damaged HDF5 metadata ({exc})") from None
    schema = schema.decode() if isinstance(schema, bytes) else schema
    kinds = {recording.SCHEMA: "recording", trajectory_file.SCHEMA: "trajectory", image_file.SCHEMA: "image"}
    if schema not in kinds:
        raise FileFormatError(f"{path}: not a sarbot file (schema attribute {schema!r}; expected one of "
                              f"{', '.join(sorted(kinds))})")
    return kinds[schema]


def _rate_hz(time_ns: np.ndarray) -> float | None:
    if time_ns.size < 2:
        return None
    return float(1e9 / np.median(np.diff(time_ns.astype(np.int64))))


def _counter_gaps(counter: np.ndarray, modulo: int) -> int:
    """Samples missing between consecutive counters (wrapping at ``modulo``)."""
    if counter.size < 2:
        return 0
    steps = np.diff(counter.astype(np.int64)) % modulo
    return int(np.sum(np.where(steps > 0, steps - 1, 0)))


def _imu_info(samples: dict, nominal_rate_hz: float, clock_drift_ppm) -> dict[str, Any]:
    """Samples, rate, counter gaps and clock drift of an IMU's recorded samples."""
    from drivers.imu import NO_COUNTER

    counter = samples["counter"].astype(np.int64)
    return {"samples": int(samples["time_ns"].size), "rate_hz": _rate_hz(samples["time_ns"]),
            "nominal_rate_hz": float(nominal_rate_hz), "counter_gaps": _counter_gaps(counter[counter != NO_COUNTER], 2**16),
            "clock_drift_ppm": None if clock_drift_ppm is None else float(clock_drift_ppm)}


def recording_info(path: str | Path) -> dict[str, Any]:
    from imaging.io.recording import Recording

    state = open_state(path)
    with Recording(path) as rec:
        out: dict[str, Any] = {"file": str(path), "kind": "recording", "state": state, "radars": {}}
        starts, ends = [], []
        for name in rec.radar_names:
            t = rec.frame_time_ns(name)
            wf = rec.radar(name).waveform
            valid = rec.valid(name) if t.size else np.zeros(0)
            info = {"frames": int(t.size), "invalid_frames": int(np.sum(valid == 0)),
                    "frame_rate_hz": _rate_hz(t), "counter_gaps": _counter_gaps(rec.frame_counter(name), 2**32),
                    "wire_format": rec.wire_format(name), "raw_adc": rec.has_adc(name),
                    "waveform": {"f0_ghz": wf.f0_hz / 1e9, "bandwidth_mhz": wf.bandwidth_hz / 1e6,
                                 "chirps_per_frame": wf.chirps_per_frame, "samples_per_chirp": wf.samples_per_chirp,
                                 "n_tx": wf.n_tx, "n_rx": wf.n_rx, "frame_interval_ms": wf.frame_interval_s * 1e3}}
            if t.size:
                info["duration_s"] = float((t[-1] - t[0]) * 1e-9)
                starts.append(int(t[0]))
                ends.append(int(t[-1]))
            radar_imu = rec.radar_imu(name)
            locked = rec.ptp_locked(name)
            if locked is not None:  # a recorder's file: the frames whose clock was not PTP-locked
                info["unlocked_frames"] = int(np.sum(~locked))
            stamp = rec.receive_stamp(name)
            if stamp is not None:  # which receive stamps timed the frames (hardware: the card's, beside the host's)
                info["receive_stamp"] = stamp
                note = rec.file[f"radar/{name}"].attrs.get("receive_stamp_note")
                if note is not None:
                    info["receive_stamp_note"] = note.decode() if isinstance(note, bytes) else str(note)
                nic = rec.nic_time_ns(name)
                if stamp == "hardware" and nic is not None:
                    info["nic_unstamped_frames"] = int(np.sum(nic == 0))
            if radar_imu is not None:  # the IMU on the radar's own mount
                attrs = rec.file[f"radar/{name}/imu"].attrs
                info["imu"] = _imu_info(radar_imu, attrs["rate_hz"], attrs.get("clock_drift_ppm"))
            out["radars"][name] = info
        imu = rec.imu()
        if imu is not None:
            out["imu"] = _imu_info(imu, imu.get("rate_hz", np.nan), imu.get("clock_drift_ppm"))
            starts.append(int(imu["time_ns"][0]))
            ends.append(int(imu["time_ns"][-1]))
        out["can_frames"] = int(rec.can()["time_ns"].size)
        out["triggers"] = int(rec.triggers().size)
        events = rec.events()
        levels: dict[str, int] = {}
        for _, _, level, _ in events:
            levels[level] = levels.get(level, 0) + 1
        out["events"] = {"count": len(events), "by_level": levels,
                         "first": [f"{source} {level}: {message}" for _, source, level, message in events[:10]]}
        out["truth"] = rec.truth() is not None
        ptp = rec.ptp()
        if ptp is not None and ptp["time_ns"].size:
            offsets = ptp["offset_from_master_ns"]
            states = list(dict.fromkeys(ptp["port_state"].tolist()))
            out["ptp"] = {"readings": int(ptp["time_ns"].size), "port_states": states,
                          "offset_ns_median": float(np.nanmedian(offsets)) if np.isfinite(offsets).any() else None,
                          "offset_ns_max_abs": float(np.nanmax(np.abs(offsets))) if np.isfinite(offsets).any() else None}
        if starts:
            out["duration_s"] = float((max(ends) - min(starts)) * 1e-9)
    return out


def trajectory_info(path: str | Path) -> dict[str, Any]:
    from imaging.io.trajectory_file import read_trajectory

    traj = read_trajectory(path)
    t = traj.time_ns
    steps = np.linalg.norm(np.diff(traj.position_m, axis=0), axis=1) if t.size > 1 else np.zeros(0)
    from imaging.io.trajectory_file import read_calibration

    calibration = {name: {"mount_translation_m": np.asarray(c["mount_translation_m"]).tolist(),
                          "mount_rotation_xyzw": np.asarray(c["mount_rotation_xyzw"]).tolist(),
                          "time_offset_s": float(c["time_offset_s"]), "sigma": np.asarray(c["sigma"]).tolist()}
                   for name, c in read_calibration(path).items()}
    out = {"file": str(path), "kind": "trajectory", "source": traj.source, "poses": int(t.size),
           "rate_hz": _rate_hz(t), "duration_s": float((t[-1] - t[0]) * 1e-9) if t.size else 0.0,
           "path_length_m": float(steps.sum()),
           # 1: the live odometry was hurried at the stop, its last poses left out; None: the file does not say.
           "stop_cut_short": traj.stop_cut_short}
    if calibration:
        out["calibration"] = calibration
    return out


def image_info(path: str | Path) -> dict[str, Any]:
    from imaging.io.image_file import read_image

    img = read_image(path)
    attrs = {k: (v.tolist() if isinstance(v, np.ndarray) else v.item() if isinstance(v, np.generic) else v)
             for k, v in img.attrs.items()}
    return {"file": str(path), "kind": "image", "shape": list(img.image.shape),
            # to the nanometre: a grid's spacing read back as a difference of centres carries rounding (0.0040000000000000036)
            "pixel_m": [round(float(np.diff(img.x_m[:2])[0]), 9) if img.x_m.size > 1 else None,
                        round(float(np.diff(img.y_m[:2])[0]), 9) if img.y_m.size > 1 else None],
            "x_m": [float(img.x_m[0]), float(img.x_m[-1])], "y_m": [float(img.y_m[0]), float(img.y_m[-1])],
            "attrs": attrs}


def info(path: str | Path) -> dict[str, Any]:
    """What the file at ``path`` holds; FileFormatError (one line naming it) for anything it cannot read,
    damaged metadata included."""
    kind = file_kind(path)
    try:
        return {"recording": recording_info, "trajectory": trajectory_info, "image": image_info}[kind](path)
    except SarbotError:  # said already, naming the file
        raise
    except (KeyError, OSError, RuntimeError, ValueError) as exc:  # a group or attribute missing or damaged
        raise FileFormatError(f"{path}: damaged or incomplete {kind} ({type(exc).__name__}: {exc})") from None


def _rotation_matrix(xyzw) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(np.asarray(xyzw, float)).as_matrix()


def _imu_line(i: dict[str, Any]) -> str:
    from .messages import imu_clock_text

    return (f"{i['samples']} samples at {i['rate_hz'] or 0:.1f} Hz, {i['counter_gaps']} missing by counter, "
            f"{imu_clock_text(i['clock_drift_ppm'])}")


_STAMP_TEXT = {"hardware": "hardware (the network card's PTP hardware clock, in nic_time_ns; host_time_ns the kernel's)",
               "software": "software (the kernel's, CLOCK_REALTIME)", "none": "none (imported)"}


def format_info(d: dict[str, Any]) -> str:
    """The info as lines a person reads."""
    lines = [f"{d['file']}: sarbot {d['kind']}"]
    if d.get("state", CLOSED) != CLOSED:
        lines[0] += (" (being written now; read up to its last flush)" if d["state"] == BEING_WRITTEN else
                     " (not closed cleanly: its recorder was stopped hard; read up to its last flush)")
    if d["kind"] == "recording":
        if "duration_s" in d:
            lines.append(f"  duration {d['duration_s']:.1f} s; truth {'yes' if d['truth'] else 'no'}; "
                         f"{d['triggers']} trigger(s); {d['can_frames']} CAN frames")
        for name, r in d["radars"].items():
            wf = r["waveform"]
            rate = f"{r['frame_rate_hz']:.2f} frames/s" if r["frame_rate_hz"] else "-"
            lines.append(f"  radar {name}: {r['frames']} frames ({rate}), {r['invalid_frames']} invalid, "
                         f"{r['counter_gaps']} missing by counter; {r['wire_format'] or 'simulated'}; "
                         f"{wf['f0_ghz']:.2f} GHz, {wf['bandwidth_mhz']:.0f} MHz, {wf['chirps_per_frame']} chirps x "
                         f"{wf['samples_per_chirp']} samples, {wf['n_tx']} TX x {wf['n_rx']} RX")
            if "receive_stamp" in r:
                lines.append(f"    receive stamps: {_STAMP_TEXT.get(r['receive_stamp'], r['receive_stamp'])}"
                             + (f"; {r['nic_unstamped_frames']} frames without one (host stamp only)"
                                if r.get("nic_unstamped_frames") else ""))
                if r.get("receive_stamp_note") and r["receive_stamp"] == "software":
                    lines.append(f"      why: {r['receive_stamp_note'].partition('): ')[2] or r['receive_stamp_note']}")
            if "imu" in r:
                lines.append(f"    its own IMU: {_imu_line(r['imu'])}")
            if r.get("unlocked_frames"):
                lines.append(f"    {r['unlocked_frames']} frames from a clock not PTP-locked (marked in /radar/{name}/ptp_locked)")
        if "imu" in d:
            lines.append(f"  IMU: {_imu_line(d['imu'])}")
        else:
            lines.append("  IMU: none")
        if "ptp" in d:
            p = d["ptp"]
            offset = "" if p["offset_ns_median"] is None else \
                f", offset from master median {p['offset_ns_median']:.0f} ns, largest {p['offset_ns_max_abs']:.0f} ns"
            lines.append(f"  host PTP: {p['readings']} readings, port {' -> '.join(p['port_states'])}{offset}")
        ev = d["events"]
        lines.append(f"  events: {ev['count']} " + (str(ev["by_level"]) if ev["count"] else ""))
        lines += [f"    {e}" for e in ev["first"]]
    elif d["kind"] == "trajectory":
        lines.append(f"  {d['source']}: {d['poses']} poses at {d['rate_hz'] or 0:.1f} Hz over {d['duration_s']:.1f} s, "
                     f"path {d['path_length_m']:.2f} m")
        if d.get("stop_cut_short"):
            lines.append("  cut short: the odometry was hurried at the stop, its last scans left out (stop_cut_short)")
        for name, c in d.get("calibration", {}).items():
            sigma = np.asarray(c["sigma"])
            yaw = float(np.degrees(np.arctan2(*np.asarray(_rotation_matrix(c["mount_rotation_xyzw"]))[[1, 0], 0])))
            lines.append(f"  calibration {name}: lever arm {np.round(c['mount_translation_m'], 4).tolist()} m "
                         f"+- {np.round(sigma[3:6] * 1e3, 1).tolist()} mm, boresight yaw {yaw:.2f} deg "
                         f"+- {np.degrees(sigma[2]):.2f}, time offset {c['time_offset_s'] * 1e3:+.2f} ms "
                         f"+- {sigma[6] * 1e3:.2f}")
    else:
        lines.append(f"  {' x '.join(map(str, d['shape']))} pixels of {d['pixel_m']} m, x {d['x_m']} m, y {d['y_m']} m")
        for key in ("radar", "frames", "n_frames", "method", "trajectory_source"):
            if key in d["attrs"]:
                lines.append(f"  {key}: {d['attrs'][key]}")
    return "\n".join(lines)
