"""The static gates beside tests/project/test_architecture.py's: ruff and mypy as pyproject.toml configures them,
the size limits of the package's files, classes and signatures (with one list of exemptions, which must
shrink), and no internal ticket numbers in the package, its tests, its docs or any tracked file's name."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "aectorch"
#: What ruff checks (experiments/ is a lab notebook, outside the gate).
RUFF_PATHS = ("aectorch", "tests", "scripts", "benchmarks", "train.py", "examples")
#: The limits in aectorch/: lines of a file, lines of a class, parameters of a function (``self`` and
#: ``cls`` not counted, keyword-only ones counted, ``*args`` and ``**kwargs`` not).
MAX_FILE_LINES = 700
MAX_CLASS_LINES = 400
MAX_PARAMETERS = 12
#: Every file, class or function over its limit, by qualified name, with the reason it may be. A name
#: that is no longer over its limit fails the test until it leaves this list.
EXEMPT = {
    "aectorch.sim.env.ActiveDepthEnv": "the head, the scene, the protocol and the trial clock (its movements, "
                                       "optics, images, object and checkpoint are collaborators) and the one-line "
                                       "delegations the package's callers use; under 450 lines",
    "aectorch.sim.env.ActiveDepthEnv.__init__": "the world's and the fixations' start settings (16), the public "
                                                "signature every caller builds the environment with",
    "aectorch.sim.hoap3.HOAP3Head": "the URDF chain and the closed-form fixations of the same head",
    "aectorch.sim.textures.bank.TextureBank": "building, indexing, splitting and moving one bank",
    "aectorch.depth.levenberg_marquardt.fit_levenberg_marquardt": "MATLAB trainlm's options, one keyword each",
    "aectorch.depth.levenberg_marquardt._train": "fit_levenberg_marquardt's loop, given the same options",
    "aectorch.ops.native._register_fake._": "the fake kernel of aectorch::render_trilinear takes the native "
                                            "op's arguments",
    "aectorch.sim.render_torch.render_planes": "a functional renderer: the poses, the scene and the camera's "
                                               "sampling as plain arguments",
    "aectorch.sim.render_torch.render_rays": "render_planes' per-pixel pass, mirrored by the fused C++ kernel",
}


def _tool(name: str) -> str:
    path = Path(sys.executable).parent / name
    if not path.exists():
        pytest.fail(f"{name} is not installed: scripts/setup.sh installs the test extra (pip install -e .[test])")
    return str(path)


@pytest.mark.integration
def test_ruff_finds_nothing():
    done = subprocess.run([_tool("ruff"), "check", "--no-cache", *RUFF_PATHS], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-2000:]


@pytest.mark.integration
def test_mypy_finds_nothing():
    # pyproject.toml's [tool.mypy] names the files; the cache (.mypy_cache) makes a second run take seconds
    done = subprocess.run([_tool("mypy")], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "Success" in done.stdout, done.stdout[-6000:] + done.stderr[-2000:]


def test_every_module_mypy_skips_exists():
    try:
        import tomllib
    except ImportError:  # Python 3.10
        tomllib = pytest.importorskip("tomli")
    overrides = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]["overrides"]
    for override in overrides:
        for module in override["module"]:
            path = ROOT.joinpath(*module.split("."))
            assert path.with_suffix(".py").is_file() or (path / "__init__.py").is_file(), module


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    names = [a.arg for a in (*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs)]
    static = any(isinstance(d, ast.Name) and d.id == "staticmethod" for d in node.decorator_list)
    return len(names) - (method and not static and bool(names) and names[0] in ("self", "cls"))


def _sizes(tree: ast.AST, prefix: str, method: bool = False):
    """``(kind, qualified name, size, limit)`` of every class (lines) and function (parameters) in ``tree``."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.ClassDef):
            name = f"{prefix}.{node.name}"
            yield "class lines", name, node.end_lineno - node.lineno + 1, MAX_CLASS_LINES
            yield from _sizes(node, name, method=True)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            name = f"{prefix}.{node.name}"
            yield "parameters", name, _parameters(node, method), MAX_PARAMETERS
            yield from _sizes(node, name)
        else:
            yield from _sizes(node, prefix, method)


def _over_limits(root: Path = ROOT, package: Path = PACKAGE) -> dict[str, str]:
    found = {}
    for path in sorted(package.rglob("*.py")):
        module = ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")
        text = path.read_text()
        sizes = [("file lines", module, len(text.splitlines()), MAX_FILE_LINES), *_sizes(ast.parse(text), module)]
        found.update({name: f"{kind}: {size} > {limit}" for kind, name, size, limit in sizes if size > limit})
    return found


def test_the_size_scan_counts_what_it_says(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    params = ", ".join(f"a{i}" for i in range(MAX_PARAMETERS))
    (package / "__init__.py").write_text(
        f"def fits({params}, *args, **kwargs): pass\n"
        f"def over({params}, *, extra): pass\n"
        "class Small:\n"
        f"    def method(self, {params}): pass\n"
        f"    @staticmethod\n    def static(self, {params}): pass\n"
        "class Long:\n" + "    x = 1\n" * MAX_CLASS_LINES)
    (package / "big.py").write_text("\n" * (MAX_FILE_LINES + 1))
    assert _over_limits(tmp_path, package) == {
        "pkg.over": f"parameters: {MAX_PARAMETERS + 1} > {MAX_PARAMETERS}",
        "pkg.Small.static": f"parameters: {MAX_PARAMETERS + 1} > {MAX_PARAMETERS}",
        "pkg.Long": f"class lines: {MAX_CLASS_LINES + 1} > {MAX_CLASS_LINES}",
        "pkg.big": f"file lines: {MAX_FILE_LINES + 1} > {MAX_FILE_LINES}",
    }


def test_no_file_class_or_signature_over_its_limit_without_a_reason():
    found = _over_limits()
    assert {name: why for name, why in found.items() if name not in EXEMPT} == {}, \
        "split these, or add them to EXEMPT with the reason"
    assert sorted(set(EXEMPT) - set(found)) == [], "within their limits now: remove them from EXEMPT"
    assert all(reason.strip() for reason in EXEMPT.values())


#: An internal ticket's number: the tracker's word for a ticket, then its number (with a space, ``_``,
#: ``-`` or ``#`` between, or none); built from pieces so that this file does not match. Upstream
#: references (``pytorch/pytorch#167288``) do not match.
TICKET = re.compile(r"(?<![a-z])iss" + r"ues?[ _#-]*[0-9]+", re.IGNORECASE)


#: Folders of a working tree that hold no tracked file (what .gitignore keeps out, and git's own).
UNTRACKED_DIRS = {"runs", "data", "outputs", "multirun", "build", "dist", "site", "__pycache__"}


def _walk() -> list[str]:
    """The tree's files outside hidden, ignored and build folders: the tracked files where git is not there."""
    names = []
    for path in ROOT.rglob("*"):
        parts = path.relative_to(ROOT).parts
        if path.is_file() and not any(p.startswith(".") or p in UNTRACKED_DIRS or p.endswith(".egg-info")
                                      for p in parts[:-1]):
            names.append("/".join(parts))
    return names


def _tracked(git: str = "git") -> list[str]:
    """git's tracked files; without git or outside a checkout (an exported tree), the walked tree's."""
    try:
        done = subprocess.run([git, "ls-files", "-z"], cwd=ROOT, capture_output=True, timeout=60)
    except FileNotFoundError:
        return _walk()
    if done.returncode != 0:
        return _walk()
    return [name for name in done.stdout.decode().split("\0") if name]


@pytest.mark.integration
def test_the_walked_tree_holds_the_tracked_files():
    walked = set(_tracked(git="no-such-git"))
    assert "aectorch/__init__.py" in walked and "tests/project/test_static_gates.py" in walked
    assert not any(name.startswith((".git/", ".venv/", "runs/")) for name in walked)
    assert set(_tracked()) - walked <= {name for name in _tracked() if name.split("/")[0].startswith(".")}


@pytest.mark.integration
def test_no_internal_ticket_numbers():
    tracked = _tracked()
    assert [name for name in tracked if TICKET.search(name)] == []
    found = []
    for name in tracked:
        if not name.startswith(("aectorch/", "tests/", "docs/")) and name != "README.md":
            continue
        data = (ROOT / name).read_bytes() if (ROOT / name).is_file() else b""
        if b"\0" in data:  # a binary file (figures, checkpoints)
            continue
        text = data.decode(errors="replace")
        found += [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group()}" for m in TICKET.finditer(text)]
    assert found == [], "say what the finding, measurement or field is instead"
