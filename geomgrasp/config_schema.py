"""Frozen config dataclasses from TOML: the one loader of geomprep's and the trainer's configs.

A field declares its default, the values it accepts and whether the paper states it
(``bounded``); ``Checked`` enforces the limits however the dataclass is made;
``build_dataclass`` fills a dataclass from a TOML table, a JSON object or command-line overrides
and words every bad value as one line naming where it came from; ``check_value`` checks one
value of one field; ``field_docs`` reads the fields' docstrings from the source. Each package
raises its own error type (``Checked.error``, the ``error`` arguments).
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import functools
import inspect
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
    paper: str | None = None,
) -> Any:
    """A dataclass field with a default and the values it accepts (for a tuple, every element),
    enforced by ``Checked.__post_init__`` however the dataclass is made (TOML, command line,
    config.json, ``dataclasses.replace``): ``substeps: int = bounded(10, ge=1)``.

    ``paper``: the setting as the paper states it (``"16384"``; words where it states several),
    for the keys of the paper's method; a field without it is the project's own (``paper_value``).
    """
    limits = {"ge": ge, "gt": gt, "le": le, "choices": choices}
    metadata: dict[str, Any] = {"limits": {k: v for k, v in limits.items() if v is not None}}
    if paper is not None:
        metadata["paper"] = paper
    return field(default=default, metadata=metadata)


def paper_value(f: dataclasses.Field) -> str | None:
    """What the paper states for field ``f`` (``bounded(..., paper=...)``), or None for a field
    that is the project's own."""
    return f.metadata.get("paper")


def field_limits(f: dataclasses.Field) -> dict[str, Any]:
    """Field ``f``'s ``bounded`` limits ({} for none)."""
    return f.metadata.get("limits", {})


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


def limits_text(limits: dict[str, Any]) -> str:
    """``bounded`` limits in words: ``>= 1``, ``one of "cpu", "warp"``."""
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
                    text = f"each element must be {limits_text(limits)}"
                    raise field_error(self.error, f.name, value, text)
            elif not _within(value, limits):
                raise field_error(self.error, f.name, value, f"must be {limits_text(limits)}")


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


def describe_type(tp: Any) -> str:
    """Annotation ``tp`` in words, for "expected ..." messages."""
    origin, args = get_origin(tp), get_args(tp)
    if origin is Literal:
        return "one of " + ", ".join(toml_value(a) for a in args)
    if origin is Union or origin is types.UnionType:
        return " or ".join(describe_type(a) for a in args if a is not type(None))
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_PLURALS.get(args[0], describe_type(args[0]))}"
        if len(set(args)) == 1 and args[0] in _PLURALS:
            return f"a list of {len(args)} {_PLURALS[args[0]]}"
        return f"a list of {len(args)} values ({', '.join(describe_type(a) for a in args)})"
    if dataclasses.is_dataclass(tp):
        return "a table (a [section])"
    words = {
        bool: "true or false", int: "an integer", float: "a number", str: "a string",
        Path: "a path (a string)",
    }
    return words.get(tp, getattr(tp, "__name__", str(tp)))


@functools.cache
def field_types(cls: type) -> dict[str, Any]:
    """The resolved annotation of each field of dataclass ``cls``."""
    return get_type_hints(cls)


def check_value(cls: type, name: str, value: Any, error: type[Exception] = UserError) -> Any:
    """``value`` for field ``name`` of dataclass ``cls`` converted as the loader converts it
    (``_convert``) and checked against the field's ``bounded`` limits, or ``error`` with the
    problem alone ("expected an integer", "must be >= 1"): the caller says where the value came
    from. Checks that span fields are left to building the dataclass."""
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    tp = field_types(cls)[name]
    try:
        converted = _convert(value, tp)
    except _WrongType as exc:
        raise error(str(exc) or f"expected {describe_type(tp)}") from None
    limits = field_limits(f)
    if limits:
        if isinstance(converted, tuple):
            if not all(_within(v, limits) for v in converted):
                raise error(f"each element must be {limits_text(limits)}")
        elif not _within(converted, limits):
            raise error(f"must be {limits_text(limits)}")
    return converted


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring of each field of class ``cls`` that has one (the string literal after the
    field, read from the source: Python keeps no attribute docstrings), dedented."""
    tree = ast.parse(inspect.cleandoc("\n" + inspect.getsource(cls)))
    body = next(node for node in tree.body if isinstance(node, ast.ClassDef)).body
    docs = {}
    for node, after in zip(body, body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
            and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def parse_value(text: str) -> Any:
    """A command-line value as TOML reads it (``0.75``, ``true``, ``[1, 2]``, ``"a b"``); a bare
    word that is not TOML (``hulls``) is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_assignment(
    text: str, option: str, example: str, error: type[Exception] = UserError
) -> tuple[str, str]:
    """``KEY=VALUE`` -> (key, value text); anything else is a one-line ``error`` naming
    ``option`` with ``example`` (a valid assignment) as the fix. The one parser of every
    command's ``--set section.key=value``."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        raise error(f"{option} {text!r}: write KEY=VALUE with KEY as section.key, e.g. {example}")
    return key.strip(), value.strip()


def nested_sets(sets: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted keys (``section.key``, deeper sections too) -> nested tables, as a TOML file
    would hold them."""
    out: dict[str, Any] = {}
    for key, value in sets.items():
        *sections, name = key.split(".")
        table = out
        for section in sections:
            table = table.setdefault(section, {})
        table[name] = value
    return out


def merge_tables(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``extra``'s values in it, tables merged key by key."""
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge_tables(out[key], value)
        else:
            out[key] = value
    return out


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
    ``section``) to the command-line option that set it, named instead: ``--seed -1: ...``, or
    to the whole assignment that set it (a name with ``=``): ``--set run.seed=-1: ...``.
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
            given = names[path]
            return given if "=" in given else f"{given} {value}"
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
        tp = field_types(cls)[key]
        if dataclasses.is_dataclass(tp) and isinstance(value, Mapping):
            kwargs[key] = build_dataclass(
                tp, value, source, error, section=f"{section}.{key}" if section else key,
                base=None if base is None else getattr(base, key), names=names,
            )
            continue
        try:
            kwargs[key] = _convert(value, tp)
        except _WrongType as exc:
            problem = str(exc) or f"expected {describe_type(tp)}"
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
