"""The recording file: HDF5 schema "sarbot.recording" version 1 (see docs/formats/recording.md), writer and reader.

Written by the recorder, the simulator and the bag importer; read by replay, RIO and imaging. The writer
creates every group and dataset up front and then switches to SWMR, so a reader (or a crash) always sees
a consistent file up to the last flush.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
from importlib import metadata
from pathlib import Path
from typing import Iterable

import h5py
import numpy as np

from imaging.core.errors import FileFormatError
from imaging.core.rig import AntennaArray, CalibrationPrior, ImuConfig, Mount, RadarConfig, Rig
from imaging.core.samples import complex_to_iq, iq_to_complex
from imaging.core.trajectory import SampledTrajectory, TrajectorySample
from imaging.core.waveform import Waveform
from imaging.io.columns import Columns
from imaging.io.schema import checksummed, open_checked, read

SCHEMA = "sarbot.recording"
SCHEMA_VERSION = 1

# Recording attribute -> Waveform field (the same names, kept explicit as the file contract).
_WAVEFORM_ATTRS = {name: name for name in (
    "f0_hz", "bandwidth_hz", "chirp_duration_s", "chirp_interval_s", "chirps_per_frame",
    "frame_interval_s", "sample_rate_hz", "n_tx", "n_rx")}


def software_version() -> str:
    try:
        return metadata.version("sarbot")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "0+unknown"


def _str_dtype():
    return h5py.string_dtype(encoding="utf-8")


def _create_imu_group(g: h5py.Group, imu: ImuConfig) -> None:
    g.attrs["rate_hz"] = imu.rate_hz
    for fld in dataclasses.fields(imu):
        if fld.name.endswith("sqrt_hz"):
            g.attrs[fld.name] = getattr(imu, fld.name)
    for name, dtype, tail in (("time_ns", np.int64, ()), ("gyro_radps", np.float64, (3,)),
                              ("accel_mps2", np.float64, (3,)), ("counter", np.uint32, ()),
                              ("host_time_ns", np.int64, ())):
        g.create_dataset(name, (0, *tail), dtype, maxshape=(None, *tail), chunks=(4096, *tail), **checksummed(dtype))


class RecordingWriter:
    """Append-only writer for one run.

    Parameters
    ----------
    path : str or Path
        File to create (an existing file is an error unless ``overwrite``).
    radars : iterable of RadarConfig
        Radars whose groups to create.
    imu : ImuConfig, optional
        Creates ``/imu`` when given.
    truth : bool
        Creates ``/truth`` (simulation only).
    wire_format : str or dict
        Stored as each radar's ``wire_format`` attribute ("SRF1", "DCA1000", "simulated"); a dict maps
        radar names to formats.
    adc_dtype : "complex64" or "int16"
        ``int16`` stores [F, chirps, rx, samples, 2] (I, Q) as received from the wire.
    root_attrs : dict, optional
        Extra attributes of ``/`` (set before SWMR starts, which forbids new attributes).
    clock_state : bool
        Also hold the clocks' state as the recorder sees it: ``/radar/NAME/ptp_locked`` [F] uint8 (the
        frame's clock said it was PTP-locked), ``/radar/NAME/nic_time_ns`` [F] int64 (the network card's
        receive stamp of the frame's last datagram, its PTP hardware clock; 0 where none) and ``/ptp/`` (the
        host's linuxptp state over time: time_ns, port_state, offset_from_master_ns, mean_path_delay_ns,
        phc2sys_offset_ns; NaN where unknown).
    events_time_base : str
        Stored as ``/events``' ``time_base`` attribute when given: ``"host"`` (the recorder) says every row's
        time is the host's CLOCK_REALTIME; without it (imports, files before it) rows may mix host and
        sensor times.
    radar_attrs : dict, optional
        Radar name -> extra attributes of its group (e.g. ``receive_stamp``), set at creation (SWMR forbids
        new attributes later).
    """

    def __init__(
        self,
        path: str | Path,
        radars: Iterable[RadarConfig],
        imu: ImuConfig | None = None,
        truth: bool = False,
        wire_format: str | dict[str, str] = "simulated",
        adc_dtype: str = "complex64",
        overwrite: bool = False,
        detections: Iterable[str] = (),
        root_attrs: dict | None = None,
        clock_state: bool = False,
        radar_attrs: dict[str, dict] | None = None,
        events_time_base: str = "",
    ):
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise FileFormatError(f"{self.path}: exists already (refusing to overwrite a recording)")
        self.radars = {r.name: r for r in radars}
        self._f = h5py.File(self.path, "w", libver="latest")
        self._columns = Columns(self._f)
        f = self._f
        f.attrs["schema"] = SCHEMA
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["created_utc"] = _dt.datetime.now(_dt.timezone.utc).isoformat()
        f.attrs["software_version"] = software_version()
        for k, v in (root_attrs or {}).items():
            f.attrs[k] = v
        for r in self.radars.values():
            g = f.create_group(f"radar/{r.name}")
            wf = r.waveform
            for attr, field in _WAVEFORM_ATTRS.items():
                g.attrs[attr] = getattr(wf, field)
            g.attrs["tx_positions_m"] = r.array.tx_positions_m
            g.attrs["rx_positions_m"] = r.array.rx_positions_m
            g.attrs["mount_translation_m"] = r.mount.translation_m
            g.attrs["mount_rotation_xyzw"] = r.mount.rotation_xyzw
            if r.calibration is not None:  # the rig's clock offset and uncertainties go with the mount
                for key, value in _calibration_attrs(r.calibration).items():
                    g.attrs[key] = value
            g.attrs["tdm_tx_order"] = np.asarray(wf.tdm_tx_order(), dtype=np.int32)
            g.attrs["wire_format"] = wire_format if isinstance(wire_format, str) else wire_format.get(r.name, "simulated")
            for k, v in (radar_attrs or {}).get(r.name, {}).items():
                g.attrs[k] = v
            shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp)
            if adc_dtype == "complex64":
                g.create_dataset("adc", (0, *shape), np.complex64, maxshape=(None, *shape), chunks=(1, *shape),
                                 fletcher32=True)
            elif adc_dtype == "int16":
                g.create_dataset("adc", (0, *shape, 2), np.int16, maxshape=(None, *shape, 2), chunks=(1, *shape, 2),
                                 fletcher32=True)
            else:
                raise ValueError(f"adc_dtype must be complex64 or int16, got {adc_dtype!r}")
            for name, dtype in (("frame_time_ns", np.int64), ("frame_counter", np.uint32),
                                ("host_time_ns", np.int64), ("valid", np.uint8)):
                g.create_dataset(name, (0,), dtype, maxshape=(None,), chunks=(1024,), fletcher32=True)
            if clock_state:
                g.create_dataset("ptp_locked", (0,), np.uint8, maxshape=(None,), chunks=(1024,), fletcher32=True)
                g.create_dataset("nic_time_ns", (0,), np.int64, maxshape=(None,), chunks=(1024,), fletcher32=True)
            if r.imu is not None:
                _create_imu_group(g.create_group("imu"), r.imu)
            if r.name in set(detections):
                d = g.create_group("detections")
                for name, dtype, tail in (("time_ns", np.int64, ()), ("scan", np.uint32, ()), ("xyz_m", np.float32, (3,)),
                                          ("doppler_mps", np.float32, ()), ("snr_db", np.float32, ())):
                    d.create_dataset(name, (0, *tail), dtype, maxshape=(None, *tail), chunks=(4096, *tail),
                                     fletcher32=True)
        if imu is not None:
            g = f.create_group("imu")
            g.attrs["mount_translation_m"] = imu.mount.translation_m
            g.attrs["mount_rotation_xyzw"] = imu.mount.rotation_xyzw
            g.attrs["clock_drift_ppm"] = np.nan  # the IMU clock against the host clock, once the driver knows it
            _create_imu_group(g, imu)
        g = f.create_group("trigger")
        g.create_dataset("time_ns", (0,), np.int64, maxshape=(None,), chunks=(256,), fletcher32=True)
        g.create_dataset("source", (0,), _str_dtype(), maxshape=(None,), chunks=(256,))  # vlen: no checksum (see checksummed)
        g = f.create_group("can")
        g.create_dataset("time_ns", (0,), np.int64, maxshape=(None,), chunks=(1024,), fletcher32=True)
        g.create_dataset("arbitration_id", (0,), np.uint32, maxshape=(None,), chunks=(1024,), fletcher32=True)
        g.create_dataset("dlc", (0,), np.uint8, maxshape=(None,), chunks=(1024,), fletcher32=True)
        g.create_dataset("data", (0, 64), np.uint8, maxshape=(None, 64), chunks=(1024, 64), fletcher32=True)
        if truth:
            g = f.create_group("truth")
            for name, tail in (("time_ns", ()), ("position_m", (3,)), ("orientation_xyzw", (4,)), ("velocity_mps", (3,))):
                g.create_dataset(name, (0, *tail), np.int64 if name == "time_ns" else np.float64,
                                 maxshape=(None, *tail), chunks=(4096, *tail), fletcher32=True)
        if clock_state:
            g = f.create_group("ptp")
            g.create_dataset("time_ns", (0,), np.int64, maxshape=(None,), chunks=(256,), fletcher32=True)
            g.create_dataset("port_state", (0,), _str_dtype(), maxshape=(None,), chunks=(256,))
            for name in ("offset_from_master_ns", "mean_path_delay_ns", "phc2sys_offset_ns"):
                g.create_dataset(name, (0,), np.float64, maxshape=(None,), chunks=(256,), fletcher32=True)
        g = f.create_group("events")
        if events_time_base:
            g.attrs["time_base"] = events_time_base
        g.create_dataset("time_ns", (0,), np.int64, maxshape=(None,), chunks=(256,), fletcher32=True)
        for name in ("source", "level", "message"):
            g.create_dataset(name, (0,), _str_dtype(), maxshape=(None,), chunks=(256,))
        f.swmr_mode = True

    # -- appending --------------------------------------------------------------------------------
    def adc_shape(self, radar: str) -> tuple[int, ...]:
        """The shape of one of ``radar``'s frames in ``adc`` (e.g. [chirps, rx, samples, 2] for int16)."""
        return self._columns[f"radar/{radar}"]["adc"].row_shape

    def append_frames(self, radar: str, adc, frame_time_ns, frame_counter, host_time_ns, valid=None) -> None:
        """Append F frames of one radar; ``adc`` complex [F, chirps, rx, samples] (or int16 with trailing 2),
        or a list of F such frames (not stacked: each is written as it is)."""
        g = self._columns[f"radar/{radar}"]
        frames = list(adc) if isinstance(adc, (list, tuple)) else np.asarray(adc)
        frame_time_ns = np.atleast_1d(np.asarray(frame_time_ns, np.int64))
        shapes = {np.shape(f) for f in frames}
        if len(frames) != frame_time_ns.size or shapes - {g["adc"].row_shape}:
            raise ValueError(f"radar {radar}: adc frames of shape {', '.join(map(str, sorted(shapes))) or 'none'} "
                             f"do not fit {g['adc'].row_shape} x {frame_time_ns.size} frames")
        g["adc"].append_rows(frames)
        g["frame_time_ns"].append(frame_time_ns)
        g["frame_counter"].append(np.atleast_1d(frame_counter).astype(np.uint32))
        g["host_time_ns"].append(np.atleast_1d(np.asarray(host_time_ns, np.int64)))
        if valid is None:
            valid = np.ones(frame_time_ns.size, np.uint8)
        g["valid"].append(np.atleast_1d(valid).astype(np.uint8))

    def append_scans(self, radar: str, frame_time_ns, frame_counter, host_time_ns, valid=None) -> None:
        """Frame (scan) bookkeeping of a radar that delivers point clouds and no ADC."""
        g = self._columns[f"radar/{radar}"]
        frame_time_ns = np.atleast_1d(np.asarray(frame_time_ns, np.int64))
        g["frame_time_ns"].append(frame_time_ns)
        g["frame_counter"].append(np.atleast_1d(frame_counter).astype(np.uint32))
        g["host_time_ns"].append(np.atleast_1d(np.asarray(host_time_ns, np.int64)))
        g["valid"].append(np.ones(frame_time_ns.size, np.uint8) if valid is None else np.atleast_1d(valid).astype(np.uint8))

    def append_detections(self, radar: str, time_ns, scan, xyz_m, doppler_mps, snr_db) -> None:
        """Detections [D] of one or more scans (sensor frame)."""
        d = self._columns[f"radar/{radar}/detections"]
        d["time_ns"].append(np.atleast_1d(np.asarray(time_ns, np.int64)))
        d["scan"].append(np.atleast_1d(scan).astype(np.uint32))
        d["xyz_m"].append(np.asarray(xyz_m, np.float32).reshape(-1, 3))
        d["doppler_mps"].append(np.atleast_1d(doppler_mps).astype(np.float32))
        d["snr_db"].append(np.atleast_1d(snr_db).astype(np.float32))

    def append_truth(self, sample: TrajectorySample) -> None:
        g = self._columns["truth"]
        g["time_ns"].append(sample.time_ns)
        g["position_m"].append(sample.position_m)
        g["orientation_xyzw"].append(sample.orientation_xyzw)
        g["velocity_mps"].append(sample.velocity_mps)

    def append_radar_imu(self, radar: str, time_ns, gyro_radps, accel_mps2, counter, host_time_ns) -> None:
        """Samples of the IMU on a radar's own mount (the radar's axes), ``/radar/<name>/imu``."""
        self._append_imu(self._columns[f"radar/{radar}/imu"], time_ns, gyro_radps, accel_mps2, counter, host_time_ns)

    def append_imu(self, time_ns, gyro_radps, accel_mps2, counter, host_time_ns) -> None:
        self._append_imu(self._columns["imu"], time_ns, gyro_radps, accel_mps2, counter, host_time_ns)

    def _append_imu(self, g, time_ns, gyro_radps, accel_mps2, counter, host_time_ns) -> None:
        g["time_ns"].append(np.asarray(time_ns, np.int64))
        g["gyro_radps"].append(gyro_radps)
        g["accel_mps2"].append(accel_mps2)
        g["counter"].append(np.asarray(counter).astype(np.uint32))
        g["host_time_ns"].append(np.asarray(host_time_ns, np.int64))

    def append_trigger(self, time_ns, source: str | list[str]) -> None:
        time_ns = np.atleast_1d(np.asarray(time_ns, np.int64))
        sources = [source] * time_ns.size if isinstance(source, str) else list(source)
        self._columns["trigger/time_ns"].append(time_ns)
        self._columns["trigger/source"].append(sources)

    def append_can(self, time_ns, arbitration_id, dlc, data) -> None:
        """CAN frames as received: ``data`` [K, <=64] uint8, padded with zeros to 64."""
        time_ns = np.atleast_1d(np.asarray(time_ns, np.int64))
        data = np.asarray(data, np.uint8).reshape(time_ns.size, -1)
        if data.shape[1] < 64:
            data = np.pad(data, ((0, 0), (0, 64 - data.shape[1])))
        g = self._columns["can"]
        g["time_ns"].append(time_ns)
        g["arbitration_id"].append(np.atleast_1d(arbitration_id).astype(np.uint32))
        g["dlc"].append(np.atleast_1d(dlc).astype(np.uint8))
        g["data"].append(data[:, :64])

    def append_frame_clock(self, radar: str, ptp_locked, nic_time_ns=0) -> None:
        """Whether each frame just appended came from a PTP-locked clock, and the network card's receive stamp
        of its last datagram (0: none) (a writer with ``clock_state``)."""
        self._columns[f"radar/{radar}/ptp_locked"].append(np.atleast_1d(ptp_locked).astype(np.uint8))
        n = np.atleast_1d(ptp_locked).size
        self._columns[f"radar/{radar}/nic_time_ns"].append(np.broadcast_to(np.asarray(nic_time_ns, np.int64), (n,)))

    def append_ptp(self, time_ns: int, port_state: str, offset_from_master_ns=None, mean_path_delay_ns=None,
                   phc2sys_offset_ns=None) -> None:
        """One reading of the host's PTP state (a writer with ``clock_state``); None is stored as NaN."""
        g = self._columns["ptp"]
        g["time_ns"].append([int(time_ns)])
        g["port_state"].append([port_state])
        for name, value in (("offset_from_master_ns", offset_from_master_ns), ("mean_path_delay_ns", mean_path_delay_ns),
                            ("phc2sys_offset_ns", phc2sys_offset_ns)):
            g[name].append([np.nan if value is None else float(value)])

    def append_event(self, time_ns: int, source: str, level: str, message: str) -> None:
        g = self._columns["events"]
        g["time_ns"].append([time_ns])
        g["source"].append([source])
        g["level"].append([level])
        g["message"].append([message])

    def has_radar_imu(self, radar: str) -> bool:
        """Whether the file has ``/radar/<radar>/imu`` (the rig declared an IMU on that radar's mount)."""
        return f"radar/{radar}/imu" in self._f

    def set_imu_clock_drift_ppm(self, drift_ppm: float, radar: str | None = None) -> None:
        """Record the IMU clock's drift against the host clock (attribute ``clock_drift_ppm`` of ``/imu``, or
        with ``radar`` of ``/radar/<radar>/imu``)."""
        key = "imu" if radar is None else f"radar/{radar}/imu"
        if key in self._f:
            self._f[key].attrs["clock_drift_ppm"] = drift_ppm

    def flush(self) -> None:
        """Write everything appended so far to the file (the page cache): a killed process loses none of it."""
        self._f.flush()

    def fileno(self) -> int:
        """The file's descriptor, for ``os.fsync`` (which takes flushed data from the page cache to the disk)."""
        return self._f.id.get_vfd_handle()

    def close(self) -> None:
        if self._f.id.valid:
            self._f.flush()
            self._f.close()
        # The columns refer to each other through their cache (a cycle the garbage collector frees only when it
        # runs): let go of them and their chunk buffers now, or each part of a split recording keeps its own.
        self._columns.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


_CALIBRATION_ATTRS = {"time_offset_s": "time_offset_s", "calibration_rotation_sigma_deg": "rotation_sigma_deg",
                      "calibration_translation_sigma_m": "translation_sigma_m",
                      "calibration_time_offset_sigma_s": "time_offset_sigma_s"}


def _calibration_attrs(prior: CalibrationPrior) -> dict:
    return {attr: np.asarray(getattr(prior, field), float) for attr, field in _CALIBRATION_ATTRS.items()
            if getattr(prior, field) is not None}


def _calibration_from_attrs(attrs) -> CalibrationPrior | None:
    """A radar's CalibrationPrior from its /radar/NAME attributes; None where the rig had none."""
    if "time_offset_s" not in attrs:
        return None
    return CalibrationPrior(**{field: (float(attrs[attr]) if np.ndim(attrs[attr]) == 0 else tuple(attrs[attr]))
                               for attr, field in _CALIBRATION_ATTRS.items() if attr in attrs})


class Recording:
    """Read access to a recording; checks the schema on open.

    Raises FileFormatError naming the file when it is missing, not HDF5 or not schema v1.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._f = open_checked(self.path, SCHEMA, SCHEMA_VERSION, "recording", libver="latest", swmr=True)
        self._mounts_from: tuple[Rig, str] | None = None

    def use_mounts_of(self, rig: Rig, source: str) -> None:
        """From now on ``radar`` gives each radar's mount and calibration (time offset) as ``rig`` has them
        (a rig ``sarbot calibrate`` refined), not as recorded; ``source`` names the rig in errors. The
        waveform and array stay the file's: they are what the samples were taken with."""
        missing = [n for n in self.radar_names if n not in {r.name for r in rig.radars}]
        if missing:
            raise FileFormatError(f"{source}: has no radar {missing[0]!r} of {self.path} "
                                  f"(its radars: {', '.join(r.name for r in rig.radars) or 'none'})")
        self._mounts_from = (rig, source)

    def close(self) -> None:
        self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def file(self) -> h5py.File:
        return self._f

    @property
    def radar_names(self) -> list[str]:
        return list(self._f["radar"].keys()) if "radar" in self._f else []

    def _radar_group(self, name: str) -> h5py.Group:
        if name not in self.radar_names:
            known = ", ".join(self.radar_names) or "none"
            raise FileFormatError(f"{self.path}: no radar named {name!r} (radars in this file: {known})")
        return self._f[f"radar/{name}"]

    def radar(self, name: str) -> RadarConfig:
        """The radar's configuration as stored in the file."""
        g = self._radar_group(name)
        try:
            integer = ("chirps_per_frame", "n_tx", "n_rx")
            wf = Waveform(**{field: int(g.attrs[attr]) if field in integer else float(g.attrs[attr])
                             for attr, field in _WAVEFORM_ATTRS.items()})
            array = AntennaArray(np.asarray(g.attrs["tx_positions_m"]), np.asarray(g.attrs["rx_positions_m"]))
            mount = Mount(np.asarray(g.attrs["mount_translation_m"]), np.asarray(g.attrs["mount_rotation_xyzw"]))
            imu = None
            if "imu" in g:
                attrs = g["imu"].attrs
                imu = ImuConfig(rate_hz=float(attrs["rate_hz"]), **{f.name: float(attrs[f.name]) for f in dataclasses.fields(ImuConfig)
                                                                    if f.name.endswith("sqrt_hz") and f.name in attrs})
            calibration = _calibration_from_attrs(g.attrs)
        except KeyError as exc:
            raise FileFormatError(f"{self.path}: /radar/{name} lacks attribute {exc.args[0]}") from None
        if self._mounts_from is not None:
            other = self._mounts_from[0].radar(name)
            mount, calibration = other.mount, other.calibration
        return RadarConfig(name, wf, array, mount, imu, calibration)

    def radar_imu(self, name: str) -> dict[str, np.ndarray] | None:
        """Samples of the IMU on the radar's own mount (time_ns, gyro_radps, accel_mps2 in the radar's
        axes, counter, host_time_ns), or None where the radar has none."""
        g = self._radar_group(name)
        if "imu" not in g or g["imu/time_ns"].shape[0] == 0:
            return None
        return {k: read(g["imu"][k]) for k in ("time_ns", "gyro_radps", "accel_mps2", "counter", "host_time_ns")}

    def tdm_tx_order(self, name: str) -> np.ndarray:
        g = self._radar_group(name)
        return np.asarray(g.attrs["tdm_tx_order"], dtype=np.int64)

    def n_frames(self, name: str) -> int:
        return int(self._radar_group(name)["frame_time_ns"].shape[0])

    def frame_time_ns(self, name: str, frames: slice = slice(None)) -> np.ndarray:
        return np.asarray(read(self._radar_group(name)["frame_time_ns"], frames), np.int64)

    def host_time_ns(self, name: str, frames: slice = slice(None)) -> np.ndarray:
        """Kernel receive times (CLOCK_REALTIME, UTC) of the frames' last datagrams."""
        return np.asarray(read(self._radar_group(name)["host_time_ns"], frames), np.int64)

    def frame_counter(self, name: str, frames: slice = slice(None)) -> np.ndarray:
        """The sensor's own frame counters, uint32."""
        return np.asarray(read(self._radar_group(name)["frame_counter"], frames), np.uint32)

    def wire_format(self, name: str) -> str | None:
        """The wire format the radar's frames arrived in ("SRF1", "DCA1000", ...; "simulated"), or None."""
        value = self._radar_group(name).attrs.get("wire_format")
        return value.decode() if isinstance(value, bytes) else value

    def valid(self, name: str, frames: slice = slice(None)) -> np.ndarray:
        return np.asarray(read(self._radar_group(name)["valid"], frames), bool)

    def has_adc(self, name: str) -> bool:
        return self._radar_group(name)["adc"].shape[0] > 0

    def has_detections(self, name: str) -> bool:
        return "detections" in self._radar_group(name)

    def detections(self, name: str) -> dict[str, np.ndarray]:
        """All detections of a radar: time_ns, scan, xyz_m (sensor frame), doppler_mps, snr_db."""
        g = self._radar_group(name)
        if "detections" not in g:
            raise FileFormatError(f"{self.path}: radar {name} has no /detections")
        return {k: read(g["detections"][k]) for k in ("time_ns", "scan", "xyz_m", "doppler_mps", "snr_db")}

    def imu_sample_count(self, radar: str | None = None) -> int:
        """How many samples ``/imu`` holds (with ``radar``: ``/radar/<radar>/imu``), without reading them."""
        key = "imu/time_ns" if radar is None else f"radar/{radar}/imu/time_ns"
        return self._f[key].shape[0] if key in self._f else 0

    def imu(self) -> dict[str, np.ndarray] | None:
        if "imu" not in self._f or self._f["imu/time_ns"].shape[0] == 0:
            return None
        g = self._f["imu"]
        out = {k: read(g[k]) for k in ("time_ns", "gyro_radps", "accel_mps2", "counter", "host_time_ns")}
        out.update({k: v for k, v in g.attrs.items()})
        return out

    def triggers(self) -> np.ndarray:
        return read(self._f["trigger/time_ns"]) if "trigger" in self._f else np.zeros(0, np.int64)

    def trigger_sources(self) -> list[str]:
        """Who saw each trigger (``/trigger/source``), in the order of ``triggers()``."""
        if "trigger" not in self._f:
            return []
        return [v.decode() if isinstance(v, bytes) else str(v) for v in read(self._f["trigger/source"])]

    def can(self) -> dict[str, np.ndarray]:
        """/can as arrays (empty when the run had no CAN traffic or the file predates it)."""
        g = self._f.get("can")
        if g is None:
            return {"time_ns": np.zeros(0, np.int64), "arbitration_id": np.zeros(0, np.uint32),
                    "dlc": np.zeros(0, np.uint8), "data": np.zeros((0, 64), np.uint8)}
        return {k: read(g[k]) for k in ("time_ns", "arbitration_id", "dlc", "data")}

    def ptp_locked(self, name: str) -> np.ndarray | None:
        """Per frame, whether the radar's clock said it was PTP-locked; None where the file does not say."""
        g = self._radar_group(name)
        return np.asarray(g["ptp_locked"][()], bool) if "ptp_locked" in g else None

    def receive_stamp(self, name: str) -> str | None:
        """Which receive stamps timed the radar's frames: "hardware" (the network card's, in ``nic_time_ns``
        beside the host's), "software" (the kernel's alone), "none" (imported); None where the file does not say."""
        value = self._radar_group(name).attrs.get("receive_stamp")
        return value.decode() if isinstance(value, bytes) else value

    def nic_time_ns(self, name: str) -> np.ndarray | None:
        """Per frame, the network card's receive stamp of its last datagram (PTP hardware clock, ns; 0 where
        none); None where the file does not hold them."""
        g = self._radar_group(name)
        return np.asarray(g["nic_time_ns"][()], np.int64) if "nic_time_ns" in g else None

    def ptp(self) -> dict[str, np.ndarray] | None:
        """/ptp (the host's linuxptp state over time) as arrays; None where the file has none."""
        if "ptp" not in self._f:
            return None
        g = self._f["ptp"]
        out = {k: g[k][()] for k in g}
        out["port_state"] = np.array([v.decode() if isinstance(v, bytes) else v for v in out["port_state"]], dtype=object)
        return out

    def events_time_base(self) -> str:
        """The clock of /events' times: ``"host"`` (CLOCK_REALTIME), or ``""`` where the file does not say
        (then rows may mix host and sensor times)."""
        value = self._f["events"].attrs.get("time_base", "")
        return value.decode() if isinstance(value, bytes) else str(value)

    def events(self) -> list[tuple[int, str, str, str]]:
        """/events as (time_ns, source, level, message) rows."""
        g = self._f["events"]
        dec = [[v.decode() if isinstance(v, bytes) else v for v in read(g[k])] for k in ("source", "level", "message")]
        return list(zip(read(g["time_ns"]).tolist(), *dec))

    def adc(self, name: str, frames: slice = slice(None)) -> np.ndarray:
        """ADC samples as complex64 [F, chirps, rx, samples] (int16 I/Q is converted)."""
        ds = self._radar_group(name)["adc"]
        if ds.shape[0] == 0 and self.n_frames(name) > 0:
            raise FileFormatError(f"{self.path}: radar {name} delivers point clouds only (no ADC frames to image)")
        data = read(ds, frames)
        return iq_to_complex(data) if ds.dtype == np.int16 else np.asarray(data, dtype=np.complex64)

    def adc_iq(self, name: str, frames: slice = slice(None)) -> np.ndarray:
        """ADC samples as int16 [F, chirps, rx, samples, 2] (I, Q), as the wire carries them; complex
        recordings are rounded and clipped to int16."""
        ds = self._radar_group(name)["adc"]
        data = read(ds, frames)
        return data if ds.dtype == np.int16 else complex_to_iq(data)

    def truth(self) -> SampledTrajectory | None:
        if "truth" not in self._f or self._f["truth/time_ns"].shape[0] < 2:
            return None
        g = self._f["truth"]
        return SampledTrajectory(*(read(g[k]) for k in ("time_ns", "position_m", "orientation_xyzw", "velocity_mps")), source="truth")
