"""Building validated dataclasses from TOML tables, with errors that name the field."""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from pathlib import Path
from typing import Any

import numpy as np

from imaging.core.errors import ConfigError


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; a missing or malformed file raises ConfigError naming it."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError("<file>", "no such file", source=str(path)) from None
    except IsADirectoryError:
        raise ConfigError("<file>", "is a folder, not a TOML file", source=str(path)) from None
    except OSError as exc:  # permissions, a device that is not a file
        raise ConfigError("<file>", f"cannot be read ({exc.strerror or exc})", source=str(path)) from None
    except UnicodeDecodeError as exc:
        raise ConfigError("<file>", f"not UTF-8 text, as TOML must be (byte {exc.start})", source=str(path)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("<file>", f"not valid TOML ({exc})", source=str(path)) from None


def _coerce(value: Any, annotation: Any, field: str) -> Any:
    origin = typing.get_origin(annotation)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(field, f"expected a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(field, f"must be finite, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(field, f"expected an integer, got {value!r}")
        return int(value)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(field, f"expected true or false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(field, f"expected a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(field, f"expected a list, got {value!r}")
        args = typing.get_args(annotation)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{field}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(field, f"expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, f"{field}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(field, f"expected a table, got {value!r}")
        return from_dict(annotation, value, prefix=field)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if value is None:
            return None
        return _coerce(value, args[0], field)
    return value


def from_dict(cls: type, table: dict[str, Any], prefix: str = "") -> Any:
    """Build dataclass ``cls`` from a TOML table, checking names and types.

    Unknown keys are errors (a typo must not silently fall back to a default). The dataclass's own
    ``__post_init__`` then checks ranges and raises ConfigError with the field name.
    """
    if not isinstance(table, dict):
        raise ConfigError(prefix or "<file>", f"expected a table, got {table!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = set(table) - set(fields)
    if unknown:
        name = sorted(unknown)[0]
        raise ConfigError(_join(prefix, name), f"unknown setting (known: {', '.join(sorted(fields))})")
    kwargs = {}
    for name, f in fields.items():
        dotted = _join(prefix, name)
        if name in table:
            kwargs[name] = _coerce(table[name], hints[name], dotted)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(dotted, "is required")
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        if prefix and not exc.field.startswith(prefix):
            raise ConfigError(_join(prefix, exc.field), str(exc).split(": ", 1)[-1]) from None
        raise
    except (TypeError, ValueError, ArithmeticError) as exc:  # a check the dataclass lacks: still name the table
        raise ConfigError(prefix or cls.__name__, f"invalid settings ({exc})") from None


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def require(condition: bool, field: str, message: str) -> None:
    """Raise ConfigError(field, message) unless condition holds."""
    if not condition:
        raise ConfigError(field, message)


def as_vector(value: Any, length: int, field: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (length,) or not np.all(np.isfinite(arr)):
        raise ConfigError(field, f"expected {length} finite numbers, got {value!r}")
    return arr
