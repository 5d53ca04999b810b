"""aectorch.runtime.command: the key=value grammar of python -m aectorch.evaluate, record and visualize."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import pytest
from omegaconf import MISSING

from aectorch.choices import Policy
from aectorch.evaluate import EvaluateConfig
from aectorch.record import RecordConfig
from aectorch.runtime.command import parse, run, usage
from aectorch.visualize.__main__ import VisualizeConfig

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class _Toy:
    """Do a toy thing.

    Args:
        name: what to call it.
        count: how many, at least 1.
        ratios: a list of numbers.
        policy: greedy or sampled.
        note: free text (default: none).
    """

    name: str = MISSING
    count: int = 2
    ratios: list[float] = dataclasses.field(default_factory=lambda: [0.5])
    policy: Policy = Policy.greedy
    note: Optional[str] = None

    def __post_init__(self) -> None:
        if self.count < 1:
            raise ValueError(f"count must be >= 1, got {self.count}")


def test_arguments_are_merged_as_yaml_and_typed_by_the_config():
    toy = parse(_Toy, ["name=x", "count=3", "ratios=[1,2.5]", "policy=sampled"])
    assert toy == _Toy(name="x", count=3, ratios=[1.0, 2.5], policy=Policy.sampled)
    assert isinstance(toy.ratios[0], float) and parse(_Toy, ["name=x"]).note is None


@pytest.mark.parametrize("argv, message", [
    (["count=3"], "name=<...> is required"),
    (["name=x", "nosuch=1"], "unknown key 'nosuch'; keys are name, count, ratios, policy, note"),
    (["name=x", "count"], "arguments are key=value, got 'count'"),
    (["name=x", "count=many"], "count: Value 'many' of type 'str' could not be converted to Integer"),
    (["name=x", "policy=argmax"], "policy: Invalid value 'argmax', expected one of [greedy, sampled]"),
    (["name=x", "ratios=[1,"], "ratios: cannot parse 'ratios=[1,'"),
    (["name=x", "ratios=fast"], "ratios must be a list such as [1.0,2.0], got 'fast'"),
    (["name=x", "count=0"], "count must be >= 1, got 0"),  # the config's own check
])
def test_bad_arguments_raise_one_message_naming_the_key(argv, message):
    with pytest.raises(ValueError) as caught:
        parse(_Toy, argv)
    assert str(caught.value).startswith(message), str(caught.value)


def test_help_comes_from_the_docstring_and_errors_are_one_line(capsys):
    text = usage(_Toy, "toy")
    assert text.startswith("usage: python -m toy name=... [key=value ...]\n\nDo a toy thing.")
    assert "  name         what to call it (required)." in text and "  count        how many, at least 1 (default: 2)." in text
    assert "  note         free text (default: none)." in text and "ratios       a list of numbers (default: [0.5])." in text
    assert run(["--help"], _Toy, "toy", lambda toy: 1) == 0 and capsys.readouterr().out == text
    assert run([], _Toy, "toy", lambda toy: 1) == 2
    assert run(["name=x"], _Toy, "toy", lambda toy: toy.count) == 2  # the body's status
    assert run(["name=x", "count=0"], _Toy, "toy", lambda toy: 0) == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith("error: count must be >= 1, got 0")


@pytest.mark.parametrize("config", [EvaluateConfig, RecordConfig, VisualizeConfig])
def test_every_key_of_the_command_lines_is_documented(config):
    text = usage(config, "command")
    for field in dataclasses.fields(config):
        line = next((line for line in text.splitlines() if line.startswith(f"  {field.name} ")), "")
        assert len(line.split()) > 2, f"{config.__name__}.{field.name} has no description under Args:"


@pytest.mark.integration
@pytest.mark.parametrize("command", ["aectorch.evaluate", "aectorch.record", "aectorch.visualize"])
def test_each_command_line_prints_its_help(command):
    done = subprocess.run([sys.executable, "-m", command, "--help"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and done.stdout.startswith(f"usage: python -m {command} checkpoint=... out=..."), \
        done.stderr[-2000:]
