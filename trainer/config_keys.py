"""Every key of the trainer's configuration, from one source: the dataclasses of
``trainer.config``, their ``bounded`` fields (default, limits, the paper's setting) and their
docstrings. ``trainer config`` prints them, ``trainer config --markdown docs/config.md`` writes
them as a page, and ``parse_sets`` checks the ``--set section.key=value`` options of the
``trainer`` commands and of the benchmarks against them.

A key is named as a TOML file writes it: ``num_envs`` (the top level), ``reward.c3`` (in
``[reward]``), ``ppo.lr``, ``run.seed``.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geomgrasp import config_schema
from geomgrasp.config_schema import (
    check_value,
    describe_type,
    field_docs,
    field_limits,
    field_types,
    limits_text,
    paper_value,
    parse_value,
    toml_value,
)
from trainer.config import EnvConfig, PPOConfig, RunConfig
from trainer.errors import TrainerError

TRAINING_SECTIONS = {"ppo": PPOConfig, "run": RunConfig}
"""The sections that configure training; a command that only builds environments (``trainer
demo``, ``grasp``, ``grasp-search``, the benchmarks) takes none of their keys."""
EVIDENCE = Path(__file__).resolve().parents[1] / "results" / "config-evidence.md"
"""The keys' history (their former docstrings), one ``### `key``` heading each."""
_RESULTS = re.compile(r"results/[\w.\-/]*\w/?")


@dataclass(frozen=True)
class Key:
    """One key of the configuration."""

    path: str
    """As a TOML file and ``--set`` write it: ``num_envs``, ``reward.c3``, ``ppo.lr``."""
    section: str
    """Its TOML section (``reward``, ``ppo``, ...); "" for the top level."""
    owner: type
    """The dataclass that holds it."""
    field: dataclasses.Field

    @property
    def name(self) -> str:
        return self.field.name

    @property
    def default(self) -> Any:
        return self.field.default

    @property
    def paper(self) -> str | None:
        """The setting as the paper states it; None: the project's own key."""
        return paper_value(self.field)

    @property
    def doc(self) -> str:
        """What the key does (its docstring, on one line)."""
        return " ".join(field_docs(self.owner).get(self.name, "").split())

    @property
    def summary(self) -> str:
        """The docstring's first sentence, without its references to results/."""
        text = re.sub(r"\s*\((?:[^()]*; )?results/[^()]*\)", "", self.doc)
        text = text.replace("``", "`")
        match = re.search(r"[.!?](\s|$)", text)
        return text[: match.start() + 1] if match else text

    @property
    def accepts(self) -> str:
        """The values it takes, in words: ``an integer >= 1``, ``one of "cpu", "warp"``."""
        limits = field_limits(self.field)
        if "choices" in limits:
            return limits_text(limits)
        kind = describe_type(field_types(self.owner)[self.name])
        if not limits:
            return kind
        each = ", each" if kind.startswith("a list") else ""
        return f"{kind}{each} {limits_text(limits)}"


def _section_keys(cls: type, section: str) -> Iterable[Key]:
    for f in dataclasses.fields(cls):
        if not dataclasses.is_dataclass(field_types(cls)[f.name]):
            yield Key(f"{section}.{f.name}" if section else f.name, section, cls, f)


def sections(training: bool = True) -> dict[str, type]:
    """Each TOML section ("" for the top level, the environment's own keys) and its dataclass,
    in the order a file would list them; ``training``: with ``[ppo]`` and ``[run]``."""
    out: dict[str, type] = {"": EnvConfig}
    for f in dataclasses.fields(EnvConfig):
        tp = field_types(EnvConfig)[f.name]
        if dataclasses.is_dataclass(tp):
            out[f.name] = tp
    return {**out, **TRAINING_SECTIONS} if training else out


def all_keys(training: bool = True) -> list[Key]:
    """Every key, section by section (``sections``)."""
    return [key for name, cls in sections(training).items() for key in _section_keys(cls, name)]


# --- --set section.key=value ---------------------------------------------------------------
def parse_assignment(text: str, option: str) -> tuple[str, str]:
    """``KEY=VALUE`` -> (key, value text); anything else is a one-line error naming ``option``
    (``geomgrasp.config_schema.parse_assignment``)."""
    return config_schema.parse_assignment(
        text, option, "robot.hand_geometry=hulls (trainer config lists the keys)", TrainerError
    )


def check_set(key: str, value: Any, given: str, training: bool = True) -> None:
    """Check one assignment (``given``: how the user wrote it, which the error names): the key
    exists (``training``: ``ppo.`` and ``run.`` keys too) and the value fits it. Every problem
    is a one-line ``TrainerError`` that says what to do instead."""
    keys = {k.path: k for k in all_keys(training=True)}
    names = sections(training=True)
    if key in names and key:
        first = next(k for k in keys.values() if k.section == key)
        raise TrainerError(
            f"{given}: [{key}] is a section: set one of its keys, e.g. "
            f"{first.path}={toml_value(first.default)} (trainer config {key} lists them)"
        )
    if key not in keys:
        section = key.partition(".")[0] if "." in key else ""
        pool = list(keys) if section in names else [*keys, *names]
        close = difflib.get_close_matches(key, pool, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise TrainerError(f"{given}: unknown key {key}{hint}: trainer config lists every key")
    found = keys[key]
    if not training and found.section in TRAINING_SECTIONS:
        raise TrainerError(
            f"{given}: [{found.section}] configures training, which this command does not run: "
            "drop it"
        )
    try:
        check_value(found.owner, found.name, value, TrainerError)
    except TrainerError as exc:
        raise TrainerError(
            f"{given}: {exc} (the default: {key} = {toml_value(found.default)})"
        ) from None


def parse_sets(
    texts: Iterable[str], option: str = "--set", training: bool = False
) -> dict[str, Any]:
    """``section.key=value`` texts -> {dotted key: value as TOML reads it (``parse_value``)},
    each checked (``check_set``; ``training``: ``ppo.`` and ``run.`` keys allowed) before any
    is used; a later one of the same key wins. The one parser of the ``trainer`` commands'
    ``--set`` and the benchmarks' ``--set`` / ``--variant``."""
    out: dict[str, Any] = {}
    for text in texts:
        key, value_text = parse_assignment(text, option)
        value = parse_value(value_text)
        check_set(key, value, f"{option} {key}={value_text}", training)
        out[key] = value
    return out


# --- trainer config ------------------------------------------------------------------------
def _heading(section: str) -> str:
    return f"[{section}]" if section else "top level (the environment)"


def _first_sentence(cls: type) -> str:
    text = " ".join((cls.__doc__ or "").split()).replace("``", "`")
    match = re.search(r"[.](\s|$)", text)
    return text[: match.start() + 1] if match else text


def select(patterns: Iterable[str], paper_only: bool = False) -> list[Key]:
    """The keys whose dotted name contains one of ``patterns`` (all without any), or whose
    section is one of them; ``paper_only``: only those the paper states."""
    patterns = list(patterns)
    chosen = [
        k for k in all_keys()
        if (not patterns or any(p == k.section or p in k.path for p in patterns))
        and (k.paper is not None or not paper_only)
    ]
    if not chosen:
        raise TrainerError(
            f"no key matches {' '.join(patterns)}: trainer config with no argument lists them all"
        )
    return chosen


def listing(keys: Iterable[Key]) -> str:
    """The text ``trainer config`` prints: per section a heading, then per key a line with its
    name, default, the values it accepts and what the paper states ("ours" where it states
    nothing), and a line with its summary."""
    keys = list(keys)
    # Columns as wide as their widest entry, up to a cap (a longer one pushes its line's rest).
    width = min(40, max(len(f"{k.path} = {toml_value(k.default)}") for k in keys))
    accepts = min(32, max(len(k.accepts) for k in keys))
    lines: list[str] = []
    section = None
    for k in keys:
        if k.section != section:
            section = k.section
            lines += [""] if lines else []
            lines.append(f"{_heading(section)}  {_first_sentence(k.owner)}")
        assignment = f"{k.path} = {toml_value(k.default)}"
        paper = f"paper: {k.paper}" if k.paper is not None else "ours"
        lines.append(f"  {assignment:<{width}}  {k.accepts:<{accepts}}  {paper}".rstrip())
        lines.append(f"      {k.summary}")
    return "\n".join(lines) + "\n"


def _evidence_anchors() -> dict[str, str]:
    """results/config-evidence.md's entry of each key that has one: key -> its anchor."""
    if not EVIDENCE.is_file():
        return {}
    headings = re.findall(r"^### `([\w.]+)`$", EVIDENCE.read_text(encoding="utf-8"), re.M)
    return {key: re.sub(r"[^\w-]", "", key.lower()) for key in headings}


def _markdown_text(text: str) -> str:
    """A docstring as Markdown: `code` spans, results/ paths as links from docs/."""
    text = text.replace("``", "`").replace("|", "\\|")
    return _RESULTS.sub(lambda m: f"[{m.group(0)}](../{m.group(0)})", text)


def markdown() -> str:
    """docs/config.md: every key of every section as a table."""
    anchors = _evidence_anchors()
    out = [
        "# The trainer's configuration",
        "",
        "<!-- Written by `trainer config --markdown docs/config.md` from trainer/config.py; do "
        "not edit (tests/test_config_keys.py checks it is up to date). -->",
        "",
        "Every key of `trainer run` and the other commands that read a config. A TOML file "
        "(`--config FILE`) sets any of them: the top-level keys at the top, the others in their "
        "`[section]` (`configs/` has the presets). `--set section.key=value` sets one on the "
        "command line (repeatable; the value as TOML writes it), as if the file said it. An "
        "option such as `--repr` wins over the file, and is refused with a `--set` of the "
        "same key. `trainer config [KEY...]` prints this list.",
        "",
        "**paper**: the setting as the paper (Mosbach & Behnke 2022) states it, for the keys of "
        "its method; `configs/paper.toml` collects them. A key without one is this project's "
        "own: something the paper does not state (MuJoCo's physics, the robot's actuation, the "
        "initial states) or an option added since (grasp starts, agent transfer, ...). The "
        "results/ folders a key links measured it; **history** links its entry in "
        "[results/config-evidence.md](../results/config-evidence.md).",
    ]
    keys = all_keys()
    for section in sections():
        mine = [k for k in keys if k.section == section]
        out += [
            "", f"## {_heading(section).capitalize()}", "",
            _markdown_text(_first_sentence(mine[0].owner)), "",
            "| key | default | accepts | paper | what it does |", "|---|---|---|---|---|",
        ]
        for k in mine:
            doc = _markdown_text(k.doc)
            if k.path in anchors:
                doc += f" ([history](../results/config-evidence.md#{anchors[k.path]}))"
            paper = _markdown_text(k.paper) if k.paper is not None else "*ours*"
            out.append(
                f"| `{k.path}` | `{toml_value(k.default)}` | {_markdown_text(k.accepts)} | "
                f"{paper} | {doc} |"
            )
    return "\n".join(out) + "\n"
