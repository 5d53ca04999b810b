"""The configuration tables of docs/training.md are generated from the config dataclasses' docstrings."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from aectorch.runtime import config_docs
from aectorch.runtime.config_docs import COMMAND, TABLES, attributes, config_classes, stale_tables, undocumented

ROOT = Path(__file__).resolve().parents[2]


def test_the_tables_in_the_docs_are_the_generated_ones():
    stale = stale_tables((ROOT / config_docs.PAGE).read_text())
    assert not stale, (f"{config_docs.PAGE}: the config tables {', '.join(stale)} are not the ones the dataclasses' "
                       f"docstrings give; regenerate them with `{COMMAND}`")


def test_every_field_of_every_config_dataclass_has_a_docstring_entry():
    missing = {cls.__qualname__: undocumented(cls) for cls in config_classes()}
    missing = {name: fields for name, fields in missing.items() if fields}
    assert not missing, (f"fields without an entry in their class docstring's Attributes: section: {missing}; "
                         f"document each there, then run `{COMMAND}`")


def test_every_config_dataclass_the_experiment_reaches_has_a_table():
    tabled = {table.cls for table in TABLES}
    nested = {cls for cls in config_classes() if cls.__name__ != "ExperimentConfig"}
    assert not nested - tabled, (f"config dataclasses without a table: {sorted(c.__name__ for c in nested - tabled)}; "
                                 f"add a Table to aectorch.runtime.config_docs.TABLES and its markers to "
                                 f"{config_docs.PAGE}, then run `{COMMAND}`")
    assert "env" in [t.name for t in TABLES] and "q_iterations" in config_docs.render(TABLES[0])


def test_a_missing_entry_and_an_edited_table_are_found():
    @dataclass
    class Toy:
        """A toy.

        Attributes:
            a, b: two fields
                on two lines.
            gone: a field that no longer exists.
        """

        a: int = 1
        b: int = 2
        c: int = 3

    assert attributes(Toy) == {"a": "two fields on two lines.", "b": "two fields on two lines.",
                               "gone": "a field that no longer exists."}
    assert undocumented(Toy) == ["c", "unknown:gone"]
    page = config_docs.update("".join(f"<!-- config-table: {t.name} -->\n<!-- /config-table -->\n" for t in TABLES))
    assert stale_tables(page) == []
    assert stale_tables(page.replace("| `q_iterations` |", "| `q_iterations_old` |")) == ["env"]
    assert stale_tables(page.replace("config-table: eval ", "config-table: evaluation ")) == ["missing:eval",
                                                                                               "unknown:evaluation"]


def test_a_cell_keeps_code_and_escapes_pipes_outside_it():
    assert config_docs._markdown("``|x|`` and :class:`Foo` | bar") == r"`|x|` and `Foo` \| bar"
