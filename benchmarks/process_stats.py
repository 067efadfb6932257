"""What a benchmark reads of a running process tree from /proc (Linux): its children, CPU time, resident
memory, time spent waiting for a core, and the machine's CPU time; of the calling process, its other threads'
CPU time, this thread's wait for a core and its main heap's free chunks. Not a benchmark itself (run_all.py
skips it); ``daemon_recording.py``, ``soak.py`` and ``ffbp.py`` import it."""

from __future__ import annotations

import ctypes
import os
import threading
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")


def child_pids(pid: int) -> list[int] | None:
    """The direct children of ``pid`` (of any of its threads), in pid order; None once it has ended."""
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except FileNotFoundError:
        return None
    children = set()
    for t in tasks:
        try:
            children.update(int(c) for c in (t / "children").read_text().split())
        except FileNotFoundError:
            continue  # a thread that ended since the listing
    return sorted(children)


def named_process_tree(pid: int, root_name: str) -> dict[int, str]:
    """``pid`` (as ``root_name``) and its children by the names they give themselves (``sarbot-imu``, ...),
    numbered where two names are the same (15 characters of a name are kept); {} once it has ended."""
    children = child_pids(pid)
    if children is None:
        return {}
    out = {pid: root_name}
    seen: dict[str, int] = {}
    for child in children:
        try:
            name = Path(f"/proc/{child}/comm").read_text().strip()
        except FileNotFoundError:
            continue
        seen[name] = seen.get(name, 0) + 1
        out[child] = name if seen[name] == 1 else f"{name}#{seen[name]}"
    return out


def rss_mb(pid: int) -> float | None:
    """Resident memory (VmRSS), MB; None once the process has ended."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except FileNotFoundError:
        return None
    return None


def cpu_s(pid: int) -> float | None:
    """User and system CPU time of the process so far, s; None once it has ended."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except FileNotFoundError:
        return None
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def run_queue_wait_s(pid: int) -> float | None:
    """How long the process's threads have waited, runnable, for a core (/proc/PID/task/*/schedstat), s."""
    total = 0.0
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except FileNotFoundError:
        return None
    for t in tasks:
        try:
            total += int((t / "schedstat").read_text().split()[1]) * 1e-9
        except (FileNotFoundError, IndexError, ValueError):
            continue  # a thread that ended since the listing
    return total


def machine_cpu_s() -> dict[str, float]:
    """All cores' time since boot from /proc/stat, s: ``busy`` (user, nice, system, interrupts), ``steal`` (taken
    by the hypervisor) and ``idle`` (with I/O wait)."""
    fields = [int(v) / CLK_TCK for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    user, nice, system, idle, iowait, irq, softirq, steal = (fields + [0.0] * 8)[:8]
    return {"busy": user + nice + system + irq + softirq, "steal": steal, "idle": idle + iowait}


def other_threads_cpu_s() -> float:
    """CPU time the calling process's other threads have run so far (their schedstat, to the nanosecond), s:
    numba's OpenMP workers spinning after a parallel region show here."""
    me, total = threading.get_native_id(), 0
    for task in Path("/proc/self/task").iterdir():
        if int(task.name) != me:
            try:
                total += int((task / "schedstat").read_text().split()[0])
            except (FileNotFoundError, IndexError, ValueError):
                continue  # a thread that ended since the listing
    return total * 1e-9


def this_thread_wait_s() -> float:
    """How long the calling thread has waited, runnable, for a core so far (its schedstat), s."""
    try:
        return int(Path(f"/proc/self/task/{threading.get_native_id()}/schedstat").read_text().split()[1]) * 1e-9
    except (FileNotFoundError, IndexError, ValueError):
        return 0.0


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                      "fsmblks", "uordblks", "fordblks", "keepcost")]


def free_heap_chunks() -> int | None:
    """Free chunks in glibc's main heap (``mallinfo2().ordblks``; None without glibc 2.33's mallinfo2): a heap
    left fragmented by earlier work makes each large allocation search longer."""
    try:
        mallinfo2 = ctypes.CDLL(None).mallinfo2
    except (OSError, AttributeError):
        return None
    mallinfo2.restype = _MallInfo2
    return int(mallinfo2().ordblks)
