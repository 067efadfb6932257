"""`sarbot batch` on a Dask LocalCluster against the same images made one after another in one process.

Four recordings (the backprojection benchmark's pass, four seeds), one image each. The baseline runs the
jobs in this process, the kernel on all cores; the batch on a LocalCluster of 2 worker processes, one
kernel thread each, already started (and, as a whole `sarbot batch` does it, with the cluster's start).
Prints the speed-up and checks the images are identical. On one 2-core machine the kernel already uses
both cores, so the gain is what the workers overlap besides it (reading, range compression, writing); a
real cluster adds machines.

    python benchmarks/batch.py [--quick]

Writes docs/results/batch.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from image_command import make_recording  # noqa: E402

from acquisition.batch import plan_jobs, run_batch, run_job  # noqa: E402
from imaging.io.image_file import read_image  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    n_frames, n_px = (4, 64) if args.quick else (8, 192)
    grid = f"-0.5:0.5:{1.0 / n_px},1.5:2.5:{1.0 / n_px},0.3"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        recs = []
        for k in range(4):
            recs.append(tmp / f"pass{k}.h5")
            make_recording(recs[-1], n_frames)
        jobs = plan_jobs(recs, grid, tmp / "single")
        (tmp / "single").mkdir()
        run_job(jobs[0])  # compile / load the kernels once, as a warm worker would have them
        t = time.perf_counter()
        single = [run_job(j) for j in jobs]
        t_single = time.perf_counter() - t
        batch_jobs = [dataclasses.replace(j, output=str(tmp / "batch" / Path(j.output).name), threads=1) for j in jobs]
        (tmp / "batch").mkdir()
        from dask.distributed import Client, LocalCluster

        t = time.perf_counter()
        batch = run_batch(batch_jobs, n_workers=2)  # what `sarbot batch` does: start a cluster, run, stop it
        t_batch_cold = time.perf_counter() - t
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            run_batch(batch_jobs[:2], client=client)  # each worker loads the kernels once
            t = time.perf_counter()
            batch = run_batch(batch_jobs, client=client)
            t_batch = time.perf_counter() - t
        identical = all(np.array_equal(read_image(a["output"]).image, read_image(b["output"]).image)
                        for a, b in zip(single, batch))
        errors = [r["error"] for r in single + batch if r["error"]]
    result = {
        "case": {"recordings": len(jobs), "frames_each": n_frames, "grid_points": n_px * n_px, "quick": args.quick},
        "single_process_s": t_single,
        "local_cluster_2_workers_s": t_batch,
        "local_cluster_2_workers_with_start_s": t_batch_cold,
        "speedup": t_single / t_batch,
        "images_identical": identical,
        "errors": errors,
        "per_job_s": {"single": [r["seconds"] for r in single], "batch": [r["seconds"] for r in batch]},
    }
    print(f"{len(jobs)} images: one process {t_single:.2f} s, LocalCluster of 2 workers {t_batch:.2f} s "
          f"({t_single / t_batch:.2f}x; {t_batch_cold:.2f} s with a cold cluster), identical: {identical}")
    name = "batch_quick" if args.quick else "batch"
    write_results(name, result, started_load=started_load)
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0 if identical and not errors else 1


if __name__ == "__main__":
    sys.exit(main())
