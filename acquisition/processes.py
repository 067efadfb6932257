"""The daemon's child processes: how each is described, started and set up, and how it logs.

Every device driver and worker runs in a process of its own, started with the ``spawn`` method (a clean
interpreter: no inherited sockets, locks or threads). A child names itself after its role, dies with
its supervisor and logs at the verbosity the command line was given (``-v``), which reaches it through
the environment.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
import signal
import socket
import tempfile
from typing import Any, Callable

#: Environment variable carrying the command line's verbosity to every child process.
VERBOSITY_ENV = "SARBOT_VERBOSITY"
#: SCHED_FIFO priority for the driver processes (the unit sets it; 0 or unset: normal scheduling).
DRIVER_RT_PRIORITY_ENV = "SARBOT_DRIVER_RT_PRIORITY"
#: Niceness of the workers (odometry, strip map): below the drivers and the recorder, so that on a busy
#: machine the live products fall behind (and say so) rather than the recording losing data. A worker that
#: others wait on (``upstream``: the odometry, whose poses the map needs before it can image a frame) is
#: niced half as much, so on a saturated machine it takes its bounded share first instead of splitting the
#: leftover evenly with the map it holds up.
WORKER_NICE_ENV = "SARBOT_WORKER_NICE"
WORKER_NICE = 10
LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"


def configure_logging(verbosity: int | None = None, role: str | None = None) -> None:
    """Log to stderr: sarbot's loggers at INFO (-v: DEBUG; -q, verbosity -1: WARNING), everything else at
    WARNING (-vv: DEBUG).

    ``verbosity`` None reads it from the environment, as a child process does; the command line sets it
    there, so every process of a run logs alike. A child's lines carry its role. Every sarbot module logs
    under "sarbot" (``logging.getLogger(f"sarbot.{__name__}")``), so ``-v`` reaches all of them.
    """
    if verbosity is None:
        verbosity = int(os.environ.get(VERBOSITY_ENV, "0") or 0)
    os.environ[VERBOSITY_ENV] = str(verbosity)
    fmt = LOG_FORMAT if role is None else f"%(levelname)s [{role}] %(name)s: %(message)s"
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter(fmt))
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbosity >= 2 else logging.WARNING)
    logging.getLogger("sarbot").setLevel(logging.DEBUG if verbosity >= 1 else logging.INFO if verbosity == 0
                                         else logging.WARNING)


def ensure_jit_cache_dir() -> str | None:
    """Make sure numba has somewhere to write its cache, and return where (None: numba's own choice, or
    ``imaging.jit_cache``'s folder keyed by the sources once imaging is imported).

    Numba caches compiled kernels beside their sources, else in the user's cache folder; under systemd's
    ``ProtectSystem=strict`` and ``ProtectHome=yes`` neither is writable and every ``cache=True`` kernel
    fails at import ("no locator available"). ``NUMBA_CACHE_DIR`` wins when set; else the unit's
    ``CacheDirectory=`` (systemd passes it as ``CACHE_DIRECTORY``); else, if the sources are read-only,
    ``$XDG_CACHE_HOME/sarbot/numba`` or a folder in the temporary directory. Set in the environment, so
    every child process uses the same cache.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    candidates = []
    if os.environ.get("CACHE_DIRECTORY"):
        candidates.append(os.path.join(os.environ["CACHE_DIRECTORY"].split(":")[0], "numba"))
    else:
        sources = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        if os.access(sources, os.W_OK):
            return None
        home_cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        candidates += [os.path.join(home_cache, "sarbot", "numba"),
                       os.path.join(tempfile.gettempdir(), f"sarbot-numba-{os.getuid()}")]
    for path in candidates:
        try:
            os.makedirs(path, mode=0o750, exist_ok=True)
        except OSError:
            continue
        if os.access(path, os.W_OK):
            os.environ["NUMBA_CACHE_DIR"] = path
            return path
    return None


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None (another C library)."""
    import ctypes
    import ctypes.util

    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = (ctypes.c_size_t,), ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Give the free pages inside the C heap back to the system (glibc's ``malloc_trim(0)``); True if
    some were. A no-op elsewhere. The workers and the daemon's recorder loop call it once a second.

    glibc raises its mmap threshold each time a mapped block is freed (up to 32 MB), so a worker that once
    freed a large array serves later arrays of a few MB from its heap, and a small long-lived allocation
    made after them keeps the heap from shrinking: the strip map's process held 850-1040 MB in a 2 m FFBP
    soak where it used 400-600 (docs/results/soak_ffbp_2m*.json). Fixing the threshold instead (1 MB, as
    db42989 did) maps and faults in every array of a MB or more each time: the odometry's point cloud took
    2.6-3.0 ms a scan with glibc's default, 5.7-7.8 ms with the threshold fixed, and the four-radar map
    lagged further for the CPU it lost. A trim costs about 16 ms for 300 MB freed, 0.15 ms for nothing.
    """
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False


def die_with_parent(name: str | None = None) -> None:
    """This process ends (SIGTERM, at once) when the one that started it does, however that ends (SIGTERM,
    SIGKILL, OOM): a child left behind would keep a port or a device busy, or keep sending. ``name``: what
    top and ps call it (15 characters kept)."""
    import multiprocessing

    parent = multiprocessing.parent_process()  # None outside a multiprocessing child
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        if name:
            libc.prctl(15, ctypes.c_char_p(name[:15].encode()), 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))
    if parent is not None and os.getppid() != parent.pid:
        os._exit(0)  # the parent died before the signal was asked for


def worker_nice(upstream: bool = False) -> int:
    """How far a worker process is niced: ``SARBOT_WORKER_NICE`` (default 10), half that (rounded down)
    for an ``upstream`` worker."""
    nice = int(os.environ.get(WORKER_NICE_ENV, WORKER_NICE) or 0)
    return nice // 2 if upstream else nice


def become_child(role: str, realtime: bool = False, background: bool = False, upstream: bool = False) -> None:
    """Set up a child process: die with the supervisor, carry the role's name, log like the parent.

    A driver whose supervisor died (SIGKILL, OOM) must not keep the port or the device busy; the name
    lets top and ps say which process is which. SIGINT is ignored (the supervisor decides when to stop:
    it sets the stop event); SIGTERM ends the process at once (a worker's own handler replaces this: it
    hurries, ``acquisition.workers.worker_process``). ``realtime``: a driver (SCHED_FIFO when
    the unit asks for it); ``background``: a worker, niced below the drivers and the recorder (``upstream``:
    one other workers wait on, niced less; ``worker_nice``).
    """
    die_with_parent(f"sarbot-{role}")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    configure_logging(role=role)
    if background:
        os.nice(worker_nice(upstream))
    priority = int(os.environ.get(DRIVER_RT_PRIORITY_ENV, "0") or 0)
    if realtime and priority > 0:
        # Only the drivers, which must drain their sockets and serial ports in time; a CPU-heavy worker at
        # real-time priority would starve them and the recorder.
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as exc:
            logging.getLogger("sarbot.acquisition.processes").warning(
                "%s: real-time priority %d not granted (%s); running at normal priority", role, priority, exc)


@dataclasses.dataclass
class ProcessSpec:
    """A child process of the daemon: ``target(*args)`` run as ``role``, restarted by the supervisor if it
    dies. ``endpoint`` is where it publishes on the bus (None for none); ``worker`` marks a process that
    finishes a product after the drivers stop and gets more time to do so."""

    role: str
    target: Callable[..., Any]
    args: tuple
    endpoint: str | None = None
    worker: bool = False


_BUS_FOLDER: str | None = None


def bus_folder() -> str:
    """This process's private folder (mode 0700) for the bus's ``ipc://`` sockets, made at first use and
    removed at exit; under systemd in the unit's $RUNTIME_DIRECTORY when it has one."""
    global _BUS_FOLDER
    if _BUS_FOLDER is None or not os.path.isdir(_BUS_FOLDER):
        import atexit
        import shutil

        parent = os.environ.get("RUNTIME_DIRECTORY", "").split(":")[0] or None
        _BUS_FOLDER = tempfile.mkdtemp(prefix="sarbot-bus-", dir=parent if parent and os.path.isdir(parent) else None)
        atexit.register(shutil.rmtree, _BUS_FOLDER, True)
    return _BUS_FOLDER


def bus_endpoint(role: str = "bus") -> str:
    """A new ``ipc://`` endpoint for a publisher on the daemon's bus, named after its ``role``.

    A Unix socket in a private folder: nothing else on the machine can take it between the moment it is
    chosen and the moment its process binds it (a loopback TCP port picked as free and bound later can be,
    and a demo lost a radar to that), and no other user can connect to it. A restarted process binds the
    same path again (ZeroMQ replaces the socket file it left).
    """
    import uuid

    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in role)[:40]
    return f"ipc://{bus_folder()}/{safe}-{uuid.uuid4().hex[:8]}"


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A loopback port free at the moment of asking (TCP by default, or socket.SOCK_DGRAM). For tests and
    benchmarks only: production code binds port 0, or uses ``bus_endpoint``."""
    return free_ports(1, kind)[0]


#: Ports this process has handed out: never handed out again, so two endpoints asked for one after the other
#: are never the same port.
_HANDED_OUT: set[int] = set()


def _ephemeral_range() -> tuple[int, int]:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            low, high = (int(v) for v in f.read().split())
        return low, high
    except (OSError, ValueError):
        return 32768, 60999


def free_ports(n: int, kind: int = socket.SOCK_DGRAM) -> list[int]:
    """``n`` distinct loopback ports, free at the moment of asking and not handed out before by this process.

    They are drawn below the kernel's ephemeral range (``ip_local_port_range``), where an outgoing connection
    never takes its local port: a port picked by binding port 0 came from that range, and between the pick
    and the bind another socket's ``connect`` could take it (a ZeroMQ socket left reconnecting by an earlier
    test does so every 100 ms), which failed a CI run with "Address already in use".
    """
    import random

    low, _ = _ephemeral_range()
    low_port = 10000 if low > 12000 else 1024
    chosen: list[int] = []
    socks: list[socket.socket] = []
    try:
        for _ in range(200 * n):
            if len(chosen) == n:
                break
            port = random.randrange(low_port, low)
            if port in _HANDED_OUT or port in chosen:
                continue
            s = socket.socket(socket.AF_INET, kind)
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                s.close()
                continue
            socks.append(s)
            chosen.append(port)
    finally:
        for s in socks:
            s.close()
    if len(chosen) < n:
        raise RuntimeError(f"free_ports: found only {len(chosen)} of {n} free loopback ports in {low_port}-{low - 1}")
    _HANDED_OUT.update(chosen)
    return chosen


def free_tcp_endpoint() -> str:
    """A loopback TCP endpoint free at the moment of asking: for tests only (see ``free_port``)."""
    return f"tcp://127.0.0.1:{free_port()}"
