"""The autofocus methods by name: one estimator function and one registry line each.

An estimator takes the group images (``imaging.autofocus.subapertures.GroupImages``) and the
``AutofocusOptions`` and returns ``(displacement_m, model, iterations)``: the track error at each group's
time ``g.time_s`` [Q] in metres (offset and drift removed: ``imaging.core.track_error.remove_line``), the
fitted model where it is parametric (a JSON-able dict, else None) and the iterations it took. What every
method shares (the contrast gate, the entropy before and after, leaving a result that does not sharpen the
image unapplied) is ``imaging.autofocus.estimate``'s, not the estimator's.

``METHODS`` is read wherever a method is chosen (``AutofocusOptions``, the strip map's ``refocus``, the
command line's choices when its parser is built), so a method registered with :func:`register_method`
before then is offered and used everywhere, with nothing else to edit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imaging.autofocus.per_profile import combined_estimate, per_profile_estimate
from imaging.autofocus.pga import pga_estimate
from imaging.autofocus.track_model import entropy_estimate

#: An estimator: (group images, options) -> (displacement per group [Q] m, model or None, iterations).
Estimator = Callable[..., tuple]

#: Method name -> estimator, in the order the command line offers them.
METHODS: dict[str, Estimator] = {}


def register_method(name: str, estimator: Estimator | None = None, *, replace: bool = False):
    """Register ``estimator`` as autofocus method ``name``; without ``estimator``, a decorator that does.

    A name already taken by another function is refused (ValueError) unless ``replace``: two plug-ins must
    not silently take each other's place.
    """
    if not isinstance(name, str) or not name or not name.replace("-", "_").isidentifier():
        raise ValueError(f"autofocus method name {name!r}: must be a word (letters, digits, _ or -)")

    def register(fn: Estimator) -> Estimator:
        if not callable(fn):
            raise TypeError(f"autofocus method {name!r}: the estimator must be callable, got {fn!r}")
        if METHODS.get(name, fn) is not fn and not replace:
            raise ValueError(f"autofocus method {name!r} is already registered (to {METHODS[name].__qualname__})")
        METHODS[name] = fn
        return fn

    return register if estimator is None else register(estimator)


def no_estimate(g, options) -> tuple[np.ndarray, None, int]:
    """The "none" method: no track error."""
    return np.zeros(g.b.shape[1]), None, 0


register_method("none", no_estimate)
register_method("pga", pga_estimate)
register_method("entropy", entropy_estimate)
register_method("per-profile", per_profile_estimate)
register_method("combined", combined_estimate)
