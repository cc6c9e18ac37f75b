"""Frozen config dataclasses from TOML: the one loader of geomprep's and the trainer's configs.

A field declares its default and the values it accepts (``bounded``); ``Checked`` enforces them
however the dataclass is made; ``build_dataclass`` fills a dataclass from a TOML table, a JSON
object or command-line overrides and words every bad value as one line naming where it came
from. Each package raises its own error type (``Checked.error``, the ``error`` arguments).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import math
import os
import tomllib
import types
from collections.abc import Mapping
from dataclasses import field
from pathlib import Path
from typing import Any, ClassVar, Literal, Union, get_args, get_origin, get_type_hints

from geomgrasp.errors import UserError


def bounded(
    default: Any,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    choices: tuple[Any, ...] | None = None,
) -> Any:
    """A dataclass field with a default and the values it accepts (for a tuple, every element),
    enforced by ``Checked.__post_init__`` however the dataclass is made (TOML, command line,
    config.json, ``dataclasses.replace``): ``substeps: int = bounded(10, ge=1)``."""
    limits = {"ge": ge, "gt": gt, "le": le, "choices": choices}
    return field(
        default=default, metadata={"limits": {k: v for k, v in limits.items() if v is not None}}
    )


def _within(value: Any, limits: dict[str, Any]) -> bool:
    try:
        return (
            ("choices" not in limits or value in limits["choices"])
            and ("ge" not in limits or value >= limits["ge"])
            and ("gt" not in limits or value > limits["gt"])
            and ("le" not in limits or value <= limits["le"])
        )
    except TypeError:  # a value of the wrong type, passed from code
        return False


def _limits_text(limits: dict[str, Any]) -> str:
    if "choices" in limits:
        return "one of " + ", ".join(toml_value(c) for c in limits["choices"])
    words = {"ge": ">=", "gt": ">", "le": "<="}
    return " and ".join(f"{words[k]} {v}" for k, v in limits.items())


def field_error(
    error: type[Exception], name: str, value: Any, problem: str
) -> Exception:
    """``error`` saying field ``name`` (holding ``value``) has ``problem``; the loader re-words it
    with where the value came from (file, section, key or command-line option)."""
    exc = error(f"{name} = {toml_value(value)}: {problem}")
    exc.config_field = name  # type: ignore[attr-defined]
    exc.config_problem = problem  # type: ignore[attr-defined]
    return exc


class Checked:
    """Base of a config dataclass: ``__post_init__`` enforces its fields' ``bounded`` limits,
    raising ``error`` (subclasses of other packages set their own)."""

    error: ClassVar[type[Exception]] = UserError

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            limits = f.metadata.get("limits")
            value = getattr(self, f.name)
            if not limits:
                continue
            if isinstance(value, tuple):
                if not all(_within(v, limits) for v in value):
                    text = f"each element must be {_limits_text(limits)}"
                    raise field_error(self.error, f.name, value, text)
            elif not _within(value, limits):
                raise field_error(self.error, f.name, value, f"must be {_limits_text(limits)}")


def toml_value(value: Any) -> str:
    """``value`` as it would be written in TOML (how messages quote what the user gave)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return json.dumps(str(value))
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


class _WrongType(Exception):
    """A value that does not fit its annotation (the loader says where and what was expected,
    or the problem given as the exception's message)."""


def _convert(value: Any, tp: Any) -> Any:
    """``value`` as annotation ``tp`` wants it (lists become tuples, strings paths, integers
    floats), or ``_WrongType``. A bool is not an integer here, although Python says it is, and
    a float is finite (TOML's inf and nan would pass every limit or silently poison a run)."""
    origin, args = get_origin(tp), get_args(tp)
    if tp is Any:
        return value
    if origin is Literal:
        if any(value == a and type(value) is type(a) for a in args):
            return value
    elif origin is Union or origin is types.UnionType:
        for arg in args:
            if arg is type(None):
                if value is None:
                    return None
                continue
            try:
                return _convert(value, arg)
            except _WrongType:
                pass
    elif origin is tuple:
        if isinstance(value, list | tuple):
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(_convert(v, args[0]) for v in value)
            if len(value) == len(args):
                return tuple(_convert(v, a) for v, a in zip(value, args, strict=True))
    elif tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # a TOML integer beyond any float
                raise _WrongType("is too large for a number") from None
            if not math.isfinite(number):
                raise _WrongType("must be a finite number (not inf or nan)")
            return number
    elif tp is str:
        if isinstance(value, str):
            return value
    elif tp is Path:
        if isinstance(value, str | os.PathLike):
            return Path(value)
    elif isinstance(tp, type) and isinstance(value, tp):
        return value
    raise _WrongType


_PLURALS = {bool: "booleans", int: "integers", float: "numbers", str: "strings", Path: "paths"}


def _describe(tp: Any) -> str:
    """Annotation ``tp`` in words, for "expected ..." messages."""
    origin, args = get_origin(tp), get_args(tp)
    if origin is Literal:
        return "one of " + ", ".join(toml_value(a) for a in args)
    if origin is Union or origin is types.UnionType:
        return " or ".join(_describe(a) for a in args if a is not type(None))
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_PLURALS.get(args[0], _describe(args[0]))}"
        if len(set(args)) == 1 and args[0] in _PLURALS:
            return f"a list of {len(args)} {_PLURALS[args[0]]}"
        return f"a list of {len(args)} values ({', '.join(_describe(a) for a in args)})"
    if dataclasses.is_dataclass(tp):
        return "a table (a [section])"
    words = {
        bool: "true or false", int: "an integer", float: "a number", str: "a string",
        Path: "a path (a string)",
    }
    return words.get(tp, getattr(tp, "__name__", str(tp)))


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return get_type_hints(cls)


def build_dataclass(
    cls: type,
    values: Mapping[str, Any],
    source: str | None,
    error: type[Exception] = UserError,
    *,
    section: str = "",
    base: Any = None,
    names: Mapping[str, str] | None = None,
) -> Any:
    """Dataclass ``cls`` from ``values`` (a TOML table, a JSON object or overrides), each value
    checked against the field's annotation and converted (see ``_convert``); a value that is a
    table fills a nested dataclass field. Fields not in ``values`` keep their defaults, or their
    values in ``base`` if given (overrides of a loaded config).

    A bad value raises ``error`` with one line naming where it came from: ``source`` (the file;
    None for overrides from the command line or code), the ``section`` (dotted), the key, the
    value, what was expected and the default as an example. ``names`` maps a key (dotted from
    ``section``) to the command-line option that set it, named instead: ``--seed -1: ...``.
    """
    place = " ".join(p for p in (source, f"[{section}]" if section else "") if p)
    if not isinstance(values, Mapping):
        raise error(
            f"{' '.join(p for p in (source, section) if p)} = {toml_value(values)}: expected a "
            f"table: write it as a [{section}] section"
        )
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}

    def label(key: str, value: Any) -> str:
        path = f"{section}.{key}" if section else key
        if names and path in names:
            return f"{names[path]} {value}"
        return f"{place} {key} = {toml_value(value)}".strip()

    def example(key: str) -> str:
        default = fields[key].default
        if source is None or default is dataclasses.MISSING:
            return ""
        return f" (the default: {key} = {toml_value(default)})"

    kwargs: dict[str, Any] = {}
    for key, value in values.items():
        if key not in fields:
            what = f"section [{key}]" if isinstance(value, Mapping) else f"key {key!r}"
            close = difflib.get_close_matches(key, fields, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise error(
                f"{place + ': ' if place else ''}unknown {what}{hint}: "
                f"valid keys are {', '.join(fields) or 'none'}"
            )
        tp = _hints(cls)[key]
        if dataclasses.is_dataclass(tp) and isinstance(value, Mapping):
            kwargs[key] = build_dataclass(
                tp, value, source, error, section=f"{section}.{key}" if section else key,
                base=None if base is None else getattr(base, key), names=names,
            )
            continue
        try:
            kwargs[key] = _convert(value, tp)
        except _WrongType as exc:
            problem = str(exc) or f"expected {_describe(tp)}"
            raise error(f"{label(key, value)}: {problem}{example(key)}") from None
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except error as exc:
        # A limit of __post_init__: say where the value came from (the field is in ``values``
        # unless a check spans fields).
        key = getattr(exc, "config_field", None)
        if key in values:
            problem = exc.config_problem  # type: ignore[attr-defined]
            raise error(f"{label(key, values[key])}: {problem}{example(key)}") from None
        if place and getattr(exc, "config_field", None):
            raise error(f"{place}: {exc}") from None
        raise


def read_toml(path: Path, error: type[Exception] = UserError) -> dict[str, Any]:
    """The TOML file at ``path`` as a dict; a missing or malformed file raises ``error`` with a
    one-line message (the trainer passes its own error type)."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))  # TOML is UTF-8
    except FileNotFoundError:
        raise error(f"config file not found: {path}: check the --config path") from None
    except UnicodeDecodeError as exc:
        raise error(
            f"config file {path} is not UTF-8 text (byte {exc.start} cannot be read): save it "
            "as UTF-8"
        ) from None
    except OSError as exc:
        raise error(f"cannot read config file {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"config file {path} is not valid TOML: {exc}") from None
