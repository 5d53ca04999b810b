"""The README's quick start runs as written (docs match the code)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_quick_start_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README.md has no python code block"
    namespace: dict = {}
    exec(compile(blocks[0], str(README), "exec"), namespace)
    assert tuple(namespace["out"].features.shape) == (8, 1152)
    assert tuple(namespace["x_hat"].shape) == (64, 113, 200)
    assert tuple(namespace["parallax"].shape) == (8, 2, 128, 128)
    assert set(namespace["stereo"]) == {"wide", "coarse", "fine", "full"}
    assert namespace["info"].errors_deg["pursuit"].shape == (8,)


def test_readme_gives_the_two_commands():
    text = README.read_text()
    assert "make train" in text and "make test" in text
