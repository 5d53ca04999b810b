"""The configuration tables of ``docs/training.md``, generated from the config dataclasses' docstrings.

Each field of a config dataclass is explained once, in the ``Attributes:`` section of its class's
docstring (the lerobot habit); the tables in the docs are rendered from those entries and the
defaults, between marker comments (``<!-- config-table: env -->`` ... ``<!-- /config-table -->``),
so they cannot drift from the code. ``tests/runtime/test_config_docs.py`` checks that the tables in the
docs are the generated ones and that every field of every config dataclass the experiment
reaches has its entry.

    python -m aectorch.runtime.config_docs            # print the tables
    python -m aectorch.runtime.config_docs --write    # rewrite them in docs/training.md
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import inspect
import re
import sys
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from aectorch.coding import EncoderConfig
from aectorch.control import ActorCriticConfig, PPOConfig
from aectorch.framework import CueConfig, LearnerConfig
from aectorch.runtime.config import (
    EnvConfig, EvalConfig, ExperimentConfig, PerturbationConfig, PlasticityConfig, RecordConfig, TrainConfig,
)
from aectorch.runtime.perturbations import PerturbationEventConfig
from aectorch.runtime.watchdog import WatchdogConfig
from aectorch.sim.scene import SceneLayout

__all__ = ["COMMAND", "TABLES", "Table", "attributes", "config_classes", "render", "stale_tables", "undocumented",
           "update"]

#: The one command that regenerates the tables (what a failing test tells its reader to run).
COMMAND = "PYTHONPATH=. .venv/bin/python -m aectorch.runtime.config_docs --write"
#: The page that holds the tables, relative to the repository's root.
PAGE = Path("docs") / "training.md"
_ROOT = Path(__file__).resolve().parents[2]
_BLOCK = re.compile(r"(<!-- config-table: (?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /config-table -->)", re.S)
_ROLE = re.compile(r":\w+:`~?([^`]+)`")
_LONG_LIST = 12


def _defaults(cls: type) -> Callable[[], dict[str, Any]]:
    return lambda: {"": cls()}


def _per_cue(part: str | None = None) -> Callable[[], dict[str, Any]]:
    """The default cues of `LearnerConfig` (or one part of each: ``encoder``, ``nac``, ``ppo``), by cue."""
    def instances() -> dict[str, Any]:
        cues = LearnerConfig().cues
        return {name: cue if part is None else getattr(cue, part) for name, cue in cues.items()}
    return instances


@dataclass(frozen=True)
class Table:
    """One generated table: the fields of ``cls`` (less ``exclude``) with their defaults and entries.

    Attributes:
        name: the table's name in its markers.
        cls: the config dataclass.
        instances: the default instances the default column shows, by label (one unlabelled instance,
            or one per cue: a field whose defaults differ shows each with its cue).
        exclude: fields the table leaves out (nested configs with tables of their own).
        defaults: whether the table has a default column.
    """

    name: str
    cls: type
    instances: Callable[[], dict[str, Any]]
    exclude: tuple[str, ...] = ()
    defaults: bool = True


#: The tables of docs/training.md, in the page's order.
TABLES: tuple[Table, ...] = (
    Table("env", EnvConfig, _defaults(EnvConfig), exclude=("scene",)),
    Table("env.scene", SceneLayout, _defaults(SceneLayout)),
    Table("learner", LearnerConfig, _defaults(LearnerConfig), exclude=("cues",)),
    Table("cue", CueConfig, _per_cue(), exclude=("encoder", "nac", "ppo")),
    Table("encoder", EncoderConfig, _per_cue("encoder")),
    Table("nac", ActorCriticConfig, _per_cue("nac")),
    Table("ppo", PPOConfig, _per_cue("ppo")),
    Table("train", TrainConfig, _defaults(TrainConfig)),
    Table("record", RecordConfig, _defaults(RecordConfig)),
    Table("watchdog", WatchdogConfig, _defaults(WatchdogConfig)),
    Table("eval", EvalConfig, _defaults(EvalConfig)),
    Table("perturbations", PerturbationEventConfig, _defaults(PerturbationEventConfig), defaults=False),
    Table("perturbation", PerturbationConfig, _defaults(PerturbationConfig)),
    Table("plasticity", PlasticityConfig, _defaults(PlasticityConfig)),
)


def attributes(cls: type) -> dict[str, str]:
    """The entries of the ``Attributes:`` section of ``cls``'s docstring, by field, as one line each.

    An entry is ``name: text`` one level below ``Attributes:``, continued by the deeper lines after
    it; ``a, b: text`` documents two fields. The section ends at the first line that is not deeper
    than its heading.

    Example:
        >>> attributes(EvalConfig)["batch_size"]
        'environments simulated at once (>= 1).'
    """
    lines = inspect.cleandoc(cls.__doc__ or "").splitlines()
    heads = [i for i, line in enumerate(lines) if line.strip() == "Attributes:"]
    if not heads:
        return {}
    indent = len(lines[heads[0]]) - len(lines[heads[0]].lstrip())
    entries: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in lines[heads[0] + 1:]:
        if not line.strip():
            continue
        depth = len(line) - len(line.lstrip())
        if depth <= indent:
            break
        match = re.match(r"([\w, ]+?):(\s|$)", line.strip())
        if depth <= indent + 4 and match:
            current = [line.strip()[match.end():].strip()]
            for name in match.group(1).split(","):
                entries[name.strip()] = current
        elif current is not None:
            current.append(line.strip())
    return {name: " ".join(part for part in text if part) for name, text in entries.items()}


def undocumented(cls: type) -> list[str]:
    """The fields of the dataclass ``cls`` without an entry in its docstring's ``Attributes:``
    (and entries that name no field, prefixed ``unknown:``)."""
    fields = [f.name for f in dataclasses.fields(cls)]
    entries = attributes(cls)
    return [name for name in fields if not entries.get(name)] + [f"unknown:{name}" for name in entries
                                                                  if name not in fields]


def config_classes(root: type = ExperimentConfig) -> list[type]:
    """Every config dataclass the experiment reaches from ``root`` through its fields' types
    (nested dataclasses, and the values of lists, tuples, dicts and optionals of them), ``root`` first."""
    found: list[type] = []
    todo: list = [root]
    while todo:
        cls = todo.pop(0)
        if cls in found:
            continue
        found.append(cls)
        for hint in typing.get_type_hints(cls).values():
            todo.extend(t for t in _types(hint) if dataclasses.is_dataclass(t) and t not in found)
    return found


def _types(hint: Any) -> list[Any]:
    args = typing.get_args(hint)
    return [hint] if not args else [t for arg in args for t in _types(arg)]


def _value(value: Any) -> str:
    if value is None:
        return "`null`"
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, enum.Enum):
        return f"`{value.value}`"
    if isinstance(value, str):
        return f"`{value}`" if value else "(required)"
    if isinstance(value, (list, tuple)):
        items = [str(v.value if isinstance(v, enum.Enum) else v) for v in value]
        if len(items) > _LONG_LIST:
            items = [*items[:2], "...", items[-1]]
        return "`[" + ", ".join(items) + "]`"
    if isinstance(value, dict) and not value:
        return "`{}`"
    return f"`{value}`"


def _default(table: Table, name: str) -> str:
    by_label = {label: _value(getattr(instance, name)) for label, instance in table.instances().items()}
    shown = set(by_label.values())
    if len(shown) == 1:
        return shown.pop()
    return ", ".join(f"{value} ({label})" for label, value in by_label.items())


def _markdown(text: str) -> str:
    """A docstring entry as one table cell: reST roles and double backticks become Markdown code, and
    a pipe outside code is escaped."""
    text = _ROLE.sub(r"`\1`", text).replace("``", "`")
    parts = text.split("`")
    return "`".join(part.replace("|", r"\|") if i % 2 == 0 else part for i, part in enumerate(parts))


def render(table: Table) -> str:
    """The Markdown table of ``table``: one row per field, in the dataclass's order."""
    entries = attributes(table.cls)
    rows = ["| field | default | meaning |" if table.defaults else "| field | meaning |",
            "|---|---|---|" if table.defaults else "|---|---|"]
    for field in dataclasses.fields(table.cls):
        if field.name in table.exclude:
            continue
        meaning = _markdown(entries.get(field.name, ""))
        default = f" {_default(table, field.name)} |" if table.defaults else ""
        rows.append(f"| `{field.name}` |{default} {meaning} |")
    return "\n".join(rows) + "\n"


def stale_tables(text: str) -> list[str]:
    """The names of the tables whose text in ``text`` (a page) is not the generated one, and of the
    tables the page lacks (``missing:<name>``) or does not know (``unknown:<name>``)."""
    tables = {table.name: table for table in TABLES}
    found = {match.group("name"): match.group("body") for match in _BLOCK.finditer(text)}
    stale = [f"missing:{name}" for name in tables if name not in found]
    stale += [f"unknown:{name}" for name in found if name not in tables]
    return stale + [name for name, body in found.items() if name in tables and body != render(tables[name])]


def update(text: str) -> str:
    """``text`` (a page) with every marked table replaced by the generated one."""
    tables = {table.name: table for table in TABLES}

    def replace(match: re.Match) -> str:
        table = tables.get(match.group("name"))
        body = render(table) if table is not None else match.group("body")
        return match.group(1) + body + match.group(4)

    return _BLOCK.sub(replace, text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aectorch.runtime.config_docs", description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help=f"rewrite the tables in {PAGE}")
    parser.add_argument("--page", type=Path, default=_ROOT / PAGE, help="the page that holds the tables")
    args = parser.parse_args(argv)
    if not args.write:
        for table in TABLES:
            print(f"<!-- config-table: {table.name} -->\n{render(table)}<!-- /config-table -->\n")
        return 0
    text = args.page.read_text()
    new = update(text)
    missing = [name for name in stale_tables(new) if ":" in name]
    if new != text:
        args.page.write_text(new)
    print(f"{args.page}: {'rewritten' if new != text else 'up to date'}"
          + (f"; no markers for {', '.join(missing)}" if missing else ""))
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
