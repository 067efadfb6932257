"""The registry of worker factories: what ``sarbot run`` starts besides the drivers and the recorder.

A worker is a ``Worker`` subclass (``acquisition.workers``) described by a ``WorkerSpec``. A *factory*
turns the daemon's setup and the run's options into the specs of the workers it wants started (none, one,
or several), and is made known with ``register``; ``assemble`` asks every registered factory in order.
``acquisition.workers.pipeline`` registers the odometry, the strip map and the live view that way; a worker
of one's own is one more call to ``register``, with no change to the pipeline, the daemon or the command
line. See docs/architecture.md for the processes of a run.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Callable

from . import WorkerSpec


@dataclasses.dataclass
class WorkerRun:
    """What a factory gets besides the setup.

    Attributes
    ----------
    out_dir : Path
        The run's folder: where the workers' products (trajectory, map) go.
    stamp : str
        The run's time stamp, for the products' file names (``trajectory_{stamp}.h5``).
    options : Any
        The run's options (``pipeline.PipelineOptions`` for ``sarbot run``).
    workers : dict of str to WorkerSpec
        The specs the factories before this one returned, by role: a worker that subscribes to another
        finds its endpoint here (the map, the odometry's poses).
    """

    out_dir: Path
    stamp: str
    options: Any
    workers: dict[str, WorkerSpec] = dataclasses.field(default_factory=dict)


#: (setup, run) -> the WorkerSpecs to start; ``setup`` is the daemon's ``Setup`` (it may set, e.g., the
#: health endpoint a worker subscribes to).
WorkerFactory = Callable[[Any, WorkerRun], "list[WorkerSpec]"]

_factories: dict[str, WorkerFactory] = {}


def register(name: str, factory: WorkerFactory) -> WorkerFactory:
    """Make ``factory`` known as ``name`` (replacing one of that name, in its place); returns it."""
    _factories[name] = factory
    return factory


def unregister(name: str) -> None:
    """Forget the factory ``name`` (nothing happens for an unknown name)."""
    _factories.pop(name, None)


def names() -> list[str]:
    """The registered factories, in the order they are asked."""
    return list(_factories)


def assemble(setup, run: WorkerRun) -> list[WorkerSpec]:
    """Every registered factory's workers for ``setup``, in registration order; also left in ``run.workers``."""
    specs: list[WorkerSpec] = []
    for factory in _factories.values():
        for spec in factory(setup, run):
            if spec.role in run.workers:
                raise ValueError(f"two workers with the role {spec.role!r}")
            run.workers[spec.role] = spec
            specs.append(spec)
    return specs
