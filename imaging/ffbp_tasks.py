"""How fast factorized backprojection (``imaging.factorized_backprojection``) cuts a level's work into tasks
and spreads them over threads: coarse tasks (a run of leaves, a range of a grid's rows), each one call of a
numba kernel that releases the GIL, taken by whichever thread is free. A core taken by another process then
only takes fewer tasks: nothing waits for it but the level's last task.
"""

from __future__ import annotations

import concurrent.futures

import numpy as np


#: Samples per task of a merge or of the pixels: large enough that a task is milliseconds, not microseconds.
TASK_SAMPLES = 16384


def row_ranges(rows: int, columns: int, threads: int) -> list:
    """Row ranges of a [rows, columns] image, each about TASK_SAMPLES (at least 4 per thread when it is
    large enough, so that an uneven split evens out)."""
    n = max(1, min(rows, max(rows * columns // TASK_SAMPLES, 4 * threads if rows * columns >= 4 * threads * 1024 else 1)))
    edges = np.linspace(0, rows, n + 1).astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def leaf_runs(leaves: list, threads: int) -> list:
    """The leaves in runs of consecutive profiles, for one call of the leaf kernel each: 4 runs a thread
    (so that a thread slowed by another process takes fewer of them), one on one thread."""
    leaves = sorted(leaves, key=lambda n: n.start)
    per_run = max(1, -(-len(leaves) // (4 * threads if threads > 1 else 1)))
    runs: list = []
    for node in leaves:
        if runs and len(runs[-1]) < per_run and runs[-1][-1].stop == node.start:
            runs[-1].append(node)
        else:
            runs.append([node])
    return runs


class Pool:
    """Run lists of tasks on ``threads`` threads, each taking the next task when it is free (on the calling
    thread alone for one thread)."""

    def __init__(self, threads: int):
        self.executor = concurrent.futures.ThreadPoolExecutor(threads) if threads > 1 else None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.executor is not None:
            self.executor.shutdown()

    def run(self, tasks: list) -> None:
        if self.executor is None or len(tasks) == 1:
            for task in tasks:
                task()
            return
        for future in [self.executor.submit(task) for task in tasks]:
            future.result()  # re-raises a task's error here
