"""`sarbot batch`: jobs planned from recordings x tiles x sweeps, run on a Dask LocalCluster of separate
worker processes, images identical to the single command's."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import point_pass

from acquisition.batch import parse_sweep, plan_jobs, run_batch, run_job
from imaging.core.errors import SarbotError
from imaging.io.image_file import read_image

CLI = [sys.executable, "-m", "acquisition.cli"]
GRID = "-0.3:0.3:0.01,1.8:2.2:0.01"


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    from imaging.sim.simulator import simulate_recording

    folder = tmp_path_factory.mktemp("batch")
    paths = []
    for k, speed in enumerate((1.0, 0.8)):
        path = folder / f"pass{k}.h5"
        simulate_recording(point_pass(speed, duration_s=0.42, seed=k), path)
        paths.append(path)
    return paths


def test_jobs_are_recordings_times_tiles_times_sweeps(recordings, tmp_path):
    sweep = parse_sweep(["mode=nearest,linear", "oversample=8,16"])
    assert sweep == [{"mode": "nearest", "oversample": 8}, {"mode": "nearest", "oversample": 16},
                     {"mode": "linear", "oversample": 8}, {"mode": "linear", "oversample": 16}]
    jobs = plan_jobs(recordings, GRID, tmp_path, tile_frames=3, sweep=sweep)
    tiles = {(j.recording, j.frames) for j in jobs}
    assert len(jobs) == len(tiles) * 4 and all(b - a <= 3 for _, (a, b) in tiles)
    assert {j.frames for j in jobs if j.recording == str(recordings[0])} == {(0, 3), (3, 6), (6, 8)}
    assert len({j.output for j in jobs}) == len(jobs)
    assert jobs[0].output.endswith("pass0_f0-3_modenearest_oversample8.h5")
    for bad, message in ((["size=1,2"], "KEY one of mode, window, oversample, algorithm, aperture_window, autofocus, aperture_m"), (["oversample=x"], "takes int values"),
                         (["mode"], "expected KEY=V1,V2")):
        with pytest.raises(SarbotError, match=message):
            parse_sweep(bad)
    with pytest.raises(SarbotError, match="oversample"):
        plan_jobs(recordings, GRID, tmp_path, sweep=[{"oversample": 0}])
    with pytest.raises(SarbotError, match="same file"):
        plan_jobs([recordings[0], recordings[0]], GRID, tmp_path)


def test_a_local_cluster_of_worker_processes_makes_the_single_commands_images(recordings, tmp_path):
    jobs = plan_jobs(recordings, GRID, tmp_path / "batch", sweep=parse_sweep(["oversample=8,16"]), threads=1)
    (tmp_path / "batch").mkdir()
    results = run_batch(jobs, n_workers=2)
    assert [r["error"] for r in results] == [None] * 4
    assert len({r["worker_pid"] for r in results}) == 2  # two separate worker processes did the work
    # The same images as `sarbot image`, bit for bit.
    for job, result in zip(jobs, results):
        single = tmp_path / f"single_{job.label}.h5"
        run = subprocess.run([*CLI, "-q", "image", job.recording, "-o", str(single), "--grid", GRID,
                              "--oversample", str(dict(job.options)["oversample"])], capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        np.testing.assert_array_equal(read_image(result["output"]).image, read_image(single).image)
        assert result["peak"] == pytest.approx(np.abs(read_image(single).image).max())


def test_tiles_of_a_drive_add_up_to_the_whole(recordings, tmp_path):
    """Backprojection is linear in the profiles: the tiles' images sum to the image of all frames."""
    whole = run_job(plan_jobs(recordings[:1], GRID, tmp_path / "whole")[0])
    tiles = [run_job(j) for j in plan_jobs(recordings[:1], GRID, tmp_path / "tiles", tile_frames=3)]
    assert whole["error"] is None and all(t["error"] is None for t in tiles) and len(tiles) == 3
    total = sum(read_image(t["output"]).image for t in tiles)
    full = read_image(whole["output"]).image
    # float32 accumulation per chunk of profiles: the sums agree to its rounding
    np.testing.assert_allclose(total, full, rtol=0, atol=1e-6 * np.abs(full).max())


def test_the_command_reports_a_broken_recording_and_keeps_the_others(recordings, tmp_path):
    broken = tmp_path / "broken.h5"
    broken.write_bytes(b"not an HDF5 file")
    out = tmp_path / "out"
    run = subprocess.run([*CLI, "-q", "batch", str(recordings[0]), str(broken), "--grid", GRID, "-o", str(out),
                          "--workers", "2"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [f"sarbot: error: broken: {broken}: not a readable HDF5 file, damaged or "
                                               "cut short (file signature not found)"]
    summary = json.loads((out / "batch.json").read_text())
    errors = {r["label"]: r["error"] for r in summary["jobs"]}
    assert errors["pass0"] is None and errors["broken"]
    assert (out / "pass0.h5").exists() and not (out / "broken.h5").exists()
    again = subprocess.run([*CLI, "-q", "batch", str(recordings[0]), "--grid", GRID, "-o", str(out)],
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and "exists already" in again.stderr  # never over an image unasked


def test_a_sweep_over_aperture_algorithm_and_autofocus(recordings, tmp_path):
    """The sweeps the studies need: the synthetic aperture (metres of track, centred in the frames), the
    algorithm and the autofocus method, each job the image `sarbot image` makes with the same options."""
    from imaging import metrics

    sweep = parse_sweep(["aperture_m=0.1,0.2", "algorithm=direct,ffbp"])
    jobs = plan_jobs(recordings[:1], GRID, tmp_path, sweep=sweep, threads=1)
    assert [(j.aperture_m, dict(j.options)["algorithm"]) for j in jobs] == [(0.1, "direct"), (0.1, "ffbp"),
                                                                           (0.2, "direct"), (0.2, "ffbp")]
    results = {(r["aperture_m"], r["options"]["algorithm"]): r for r in map(run_job, jobs)}
    assert all(r["error"] is None for r in results.values()), results
    images = {k: read_image(r["output"]) for k, r in results.items()}
    width = {}
    for aperture in (0.1, 0.2):
        direct, ffbp = images[(aperture, "direct")], images[(aperture, "ffbp")]
        assert abs(direct.attrs["aperture_length_m"] / aperture - 1) < 0.03, direct.attrs["aperture_length_m"]
        err = np.sum(np.abs(ffbp.image - direct.image) ** 2) / np.sum(np.abs(direct.image) ** 2)
        assert 10 * np.log10(err) < -35
        a = metrics.analyze_target(direct.image, direct.x_m, direct.y_m, direct.attrs["look_direction"], near_m=(0.0, 2.0),
                                   radius_m=0.1, half_length_m=0.25)
        width[aperture] = a["cross_range"]["half_power_width_m"]
    assert 1.7 < width[0.1] / width[0.2] < 2.3  # twice the aperture, half the width
    # The single command with the same options makes the same image, bit for bit.
    single = tmp_path / "single.h5"
    run = subprocess.run([*CLI, "-q", "image", str(recordings[0]), "-o", str(single), "--grid", GRID,
                          "--aperture", "0.2", "--algorithm", "ffbp"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    np.testing.assert_array_equal(read_image(single).image, images[(0.2, "ffbp")].image)
    # Autofocus as a sweep axis: the method is in the image file and the summary.
    focused = run_job(plan_jobs(recordings[:1], GRID, tmp_path / "af", sweep=parse_sweep(["autofocus=entropy"]))[0])
    assert focused["error"] is None and focused["autofocus"] == "entropy"
    assert read_image(focused["output"]).attrs["autofocus"] == "entropy"
    # So is the taper over the aperture.
    tapered = run_job(plan_jobs(recordings[:1], GRID, tmp_path / "taper", sweep=parse_sweep(["aperture_window=taylor"]))[0])
    assert tapered["error"] is None and tapered["options"]["aperture_window"] == "taylor"
    assert read_image(tapered["output"]).attrs["aperture_window"] == "taylor"
    # An aperture longer than the track is the job's error, naming the track's length; bad values fail at once.
    long = run_job(plan_jobs(recordings[:1], GRID, tmp_path / "long", sweep=parse_sweep(["aperture_m=1.0"]))[0])
    assert "shorter than the aperture of 1.0 m" in long["error"] and "the track is 0.4" in long["error"]
    for bad, message in ((["aperture_m=x"], "takes float values"), (["algorithm=magic"], "algorithm"),
                         (["autofocus=magic"], "method"), (["aperture_m=-1"], "positive length"),
                         (["aperture_window=magic"], "aperture_window")):
        with pytest.raises(SarbotError, match=message):
            plan_jobs(recordings[:1], GRID, tmp_path, sweep=parse_sweep(bad))


def test_the_dask_dashboard_is_served_on_loopback_and_its_address_printed(recordings, tmp_path):
    """With bokeh installed (the dashboard extra, in the test extra), the local cluster serves Dask's
    dashboard: its page comes over HTTP while the batch runs, and ``sarbot batch`` prints its address."""
    import re
    import urllib.request

    pytest.importorskip("bokeh", reason="the dashboard needs bokeh: pip install 'sarbot[dashboard]'")
    pages = []

    def fetch(link):
        assert link is not None and link.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(link, timeout=30) as answer:  # the dashboard's status page
            pages.append((answer.status, answer.read().decode()))

    jobs = plan_jobs(recordings[:1], GRID, tmp_path / "api", threads=1)
    results = run_batch(jobs, n_workers=1, dashboard_address="127.0.0.1:0", on_dashboard=fetch)
    assert results[0]["error"] is None
    ((status, page),) = pages
    assert status == 200 and "Dask" in page and "bokeh" in page.lower()
    # The command says where it is.
    run = subprocess.run([*CLI, "batch", str(recordings[0]), "--grid", GRID, "-o", str(tmp_path / "cli"), "--workers", "1",
                          "--dashboard", "127.0.0.1:0"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert re.search(r"Dask dashboard: http://127\.0\.0\.1:\d+/status", run.stderr), run.stderr
    quiet = subprocess.run([*CLI, "batch", str(recordings[0]), "--grid", GRID, "-o", str(tmp_path / "none"), "--workers",
                            "1", "--dashboard", "none"], capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 0 and "dashboard" not in quiet.stderr, quiet.stderr
