"""The documentation: the tutorial's code runs as written, and the site builds with warnings as errors."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.integration
def test_tutorial_code_runs_in_order(tmp_path):
    text = (ROOT / "docs" / "tutorial-torch.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 5
    script = tmp_path / "tutorial.py"
    script.write_text("\n".join(blocks))
    env = dict(os.environ, OMP_NUM_THREADS="1")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, env=env,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "error" in done.stdout and "mean |disparity|" in done.stdout
    # Every print marked `# -> <text>` printed <text>, in order.
    expected = re.findall(r"print\(.*?\)\s*# -> (.*)", "\n".join(blocks))
    assert len(expected) >= 2
    printed = done.stdout.splitlines()
    for line in expected:
        assert line.strip() in [p.strip() for p in printed], (line, printed)


def test_every_result_file_is_cited_and_every_cited_one_exists():
    """``benchmarks/results`` (speed) and ``docs/measurements`` (learning): a file no page cites is a lab
    notebook's leftover; a cited path (or glob) that matches nothing is a broken reference."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    text = "\n".join(page.read_text() for page in pages)
    for folder in ("benchmarks/results", "docs/measurements"):
        # ``<commit>:benchmarks/results/...`` names a file in git history (``git show``), not the tree
        cited = set(re.findall(r"(?<![0-9a-f]{7}:)" + re.escape(folder) + r"/([A-Za-z0-9_.*-]+\.json)", text))
        for pattern in sorted(cited):
            assert list((ROOT / folder).glob(pattern)), f"cited but missing: {folder}/{pattern}"
        for path in sorted((ROOT / folder).iterdir()):
            assert any(Path(path.name).match(pattern) for pattern in cited) or path.name in text, \
                f"{folder}/{path.name} is cited by no page of docs/ or the README"


@pytest.mark.integration
def test_site_builds_strictly(tmp_path):
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    if mkdocs is None:
        pytest.fail("mkdocs is missing: scripts/setup.sh installs the docs extra (pip install -e .[docs])")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    done = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-5000:]
    api = (tmp_path / "site" / "api" / "coding" / "index.html").read_text()
    assert "Batched orthogonal matching pursuit" in api  # the reference comes from the docstrings
    for page in ("tutorial-torch", "lerobot", "results", "performance", "paper-mapping", "architecture"):
        assert (tmp_path / "site" / page / "index.html").is_file(), page
