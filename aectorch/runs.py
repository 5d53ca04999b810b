"""Reading a run folder: what ``train.py`` wrote, as plain Python data.

A run folder (`aectorch.runtime.RunFolder` writes it) holds ``config.yaml`` (the resolved
config), ``metrics.jsonl`` (a line every ``train.log_every`` iterations), ``summary.json``
(final metrics, timing, the perturbation's recovery), ``provenance.json`` and evaluations
(``evaluation.json`` at the end of training; ``python -m aectorch.evaluate ... out=<run>/<name>.json``
adds others), each with ``per_trial`` rows. `Run` reads them, once each; `read_metrics` and
`read_json` read one file. ``python -m aectorch.report``, the runtime's finish, the figures and the
tests all read runs through this module.

Example:
    >>> import json, tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "metrics.jsonl").write_text('{"iteration": 10, "pursuit_mae_deg": 0.5}\\n')
    >>> _ = (folder / "evaluation.json").write_text(json.dumps({"per_trial": [{"distance_m": 1.0}]}))
    >>> run = Run(folder)
    >>> run.metrics_at[10] == {"iteration": 10, "pursuit_mae_deg": 0.5}
    True
    >>> len(run.per_trial())
    1
"""

from __future__ import annotations

import json
import os
import warnings
from functools import cached_property
from pathlib import Path

__all__ = ["EVALUATION", "Run", "checkpoint_source", "file_sha256", "files_read", "forget_files_read", "per_trial_rows",
           "read_json", "read_metrics"]

#: The evaluation written at the end of training (``eval.enabled``).
EVALUATION = "evaluation.json"


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    import hashlib

    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def checkpoint_source(path: str | os.PathLike, iteration: int) -> dict:
    """What an evaluation was made from, as it records it (``"source"``): the checkpoint's file
    name, its iteration and the SHA-256 of its bytes. `Run.evaluation` checks it against the run's
    file of that name, so a result of an earlier checkpoint does not pass for the current one."""
    return {"checkpoint": Path(path).name, "iteration": int(iteration), "sha256": file_sha256(path)}


#: The run files read since `forget_files_read` (``python -m aectorch.report`` names them when a
#: value in one of them is not what aectorch writes).
_FILES_READ: list[Path] = []


def files_read() -> list[Path]:
    """The run files read (`read_json`, `read_metrics`, `Run.config`) since `forget_files_read`."""
    return list(dict.fromkeys(_FILES_READ))


def forget_files_read() -> None:
    _FILES_READ.clear()


def _read_text(path: Path) -> str:
    _FILES_READ.append(path)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:  # a flipped bit, another file's bytes
        raise ValueError(f"{path} is not UTF-8 text (byte {exc.start}: damaged?)") from None


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def read_json(path: str | os.PathLike) -> dict:
    """One JSON file of a run, as a dict.

    Raises:
        FileNotFoundError: no such file (the message names it).
        ValueError: the file is not a JSON object.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        data = json.loads(_read_text(path))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not valid JSON ({exc.msg}, line {exc.lineno})") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path} must hold a JSON object, got {type(data).__name__}")
    return data


def read_metrics(path: str | os.PathLike) -> list[dict]:
    """Read a ``metrics.jsonl`` file: one JSON object per line.

    Blank lines are skipped. A last line that does not parse (a run that crashed mid-write) is
    skipped with a :func:`warnings.warn`; a bad line elsewhere is a ``ValueError``.

    Args:
        path: the ``.jsonl`` file.

    Returns:
        The records, in file order.

    Example:
        >>> import tempfile
        >>> f = Path(tempfile.mkdtemp()) / "metrics.jsonl"
        >>> _ = f.write_text('{"iteration": 1, "pursuit_mae_deg": 2.5}\\n\\n{"iteration": 2, "pursu')
        >>> with warnings.catch_warnings(record=True):
        ...     read_metrics(f)
        [{'iteration': 1, 'pursuit_mae_deg': 2.5}]
    """
    path = Path(path)
    records: list[dict] = []
    for number, record in _json_lines(path):
        if not _is_int(record.get("iteration")):
            raise ValueError(f"{path}: line {number} needs an integer 'iteration', got {record.get('iteration')!r}")
        # (a line holds numbers, null for an undefined one, and lists of names: the events acting)
        bad = [k for k, v in record.items() if not (v is None or isinstance(v, (int, float)) and not isinstance(v, bool)
                                                    or isinstance(v, list) and all(isinstance(x, str) for x in v))]
        if bad:
            raise ValueError(f"{path}: line {number}'s {bad[0]!r} must be a number, got {record[bad[0]]!r}")
        records.append(record)
    return records


def _json_lines(path: Path) -> list[tuple[int, dict]]:
    """A JSON-lines file's objects with their line numbers, blank lines skipped; a torn last
    line (a run killed mid-write) is skipped with a warning (``stacklevel`` 3: the reader's caller).

    Raises:
        ValueError: a line before the last is not JSON, or a line is not a JSON object.
    """
    lines = [(number, line.strip()) for number, line in enumerate(_read_text(path).splitlines(), start=1)]
    lines = [(number, line) for number, line in lines if line]
    out = []
    for position, (number, line) in enumerate(lines):
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            if position == len(lines) - 1:
                warnings.warn(f"{path}: skipping truncated last line {number} ({exc.msg})", stacklevel=3)
                break
            raise ValueError(f"{path}: line {number} is not valid JSON ({exc.msg})") from exc
        if not isinstance(record, dict):
            raise ValueError(f"{path}: line {number} must be a JSON object, got {type(record).__name__}")
        out.append((number, record))
    return out


class Run:
    """The files of one run folder, each read on first use.

    Args:
        path: the run folder (``hydra.run.dir`` of ``train.py``).

    Raises:
        FileNotFoundError: ``path`` is not a folder; a file asked for is missing (named).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"run folder {str(self.path)!r}: no such folder")
        self._evaluations: dict[str, dict] = {}

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r})"

    @property
    def name(self) -> str:
        """The folder's name."""
        return self.path.name

    def has(self, name: str) -> bool:
        """Whether the run holds the file ``name``."""
        return (self.path / name).is_file()

    @cached_property
    def config(self) -> dict:
        """``config.yaml`` as nested dicts (as written: interpolations unresolved)."""
        from omegaconf import OmegaConf

        path = self.path / "config.yaml"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such file")
        try:
            config = OmegaConf.to_container(OmegaConf.create(_read_text(path)), resolve=False)
        except Exception as exc:  # noqa: BLE001 - YAML's and OmegaConf's parse errors
            raise ValueError(f"{path} is not a config aectorch wrote ({type(exc).__name__})") from exc
        if not isinstance(config, dict):
            raise ValueError(f"{path} must hold a mapping, got {type(config).__name__}")
        return config

    @cached_property
    def metrics(self) -> list[dict]:
        """``metrics.jsonl``'s lines in file order (`read_metrics`)."""
        path = self.path / "metrics.jsonl"
        if not path.is_file():
            raise FileNotFoundError(f"run {str(self.path)!r} has no metrics.jsonl")
        return read_metrics(path)

    @cached_property
    def metrics_at(self) -> dict[int, dict]:
        """``metrics.jsonl``'s lines by their iteration."""
        return {line["iteration"]: line for line in self.metrics}

    @cached_property
    def code_readouts(self) -> list[dict]:
        """``code_readouts.jsonl``'s lines in file order (``train.readout_every``): each
        ``{"iteration": N, "code": {dictionary: code_summary}}``; ``[]`` when the run has none.
        A torn last line (a run killed mid-write) is skipped with a warning, as `read_metrics` does."""
        path = self.path / "code_readouts.jsonl"
        if not path.is_file():
            return []
        readouts = []
        for number, record in _json_lines(path):
            if not (_is_int(record.get("iteration")) and isinstance(record.get("code"), dict)):
                raise ValueError(f"{path}: line {number} must be an object with an integer 'iteration' and a 'code'")
            readouts.append(record)
        return readouts

    @cached_property
    def summary(self) -> dict:
        """``summary.json``: the final training window, timing, best state, perturbation, evaluation."""
        return read_json(self.path / "summary.json")

    @cached_property
    def code(self) -> dict:
        """The read-outs of the run's learned code: ``summary.json``'s ``"code"``
        (``{dictionary: code_summary}``), with its ``"code_initial"`` under the key ``"initial"``
        when the summary holds it (`aectorch.coding.readouts.code_summary`).

        Raises:
            KeyError: the summary has no ``"code"`` (a run from before the read-outs:
                ``python train.py train.resume=<run>`` finishes it again).
        """
        summary = self.summary
        if "code" not in summary:
            raise KeyError(f"{self.path / 'summary.json'} has no 'code' entry: written before the code's read-outs "
                           f"(python train.py train.resume={self.path} finishes it again)")
        code = dict(summary["code"])
        if "code_initial" in summary:
            code["initial"] = summary["code_initial"]
        return code

    @cached_property
    def provenance(self) -> dict:
        """``provenance.json``: versions, commit, device and machine of each session."""
        return read_json(self.path / "provenance.json")

    def evaluation(self, name: str = EVALUATION) -> dict:
        """An evaluation of the run (``evaluation.json`` by default, or another file in the folder).

        Raises:
            ValueError: the evaluation was made from another checkpoint than the run's file of
                that name holds now (its ``"source"``: `checkpoint_source`), e.g. one left by an
                earlier run in the folder.
        """
        if name not in self._evaluations:
            evaluation = read_json(self.path / name)
            self._check_source(evaluation, self.path / name)
            self._evaluations[name] = evaluation
        return self._evaluations[name]

    def _check_source(self, evaluation: dict, path: Path) -> None:
        source = evaluation.get("source")
        if source is None:  # written before evaluations recorded their checkpoint's hash
            self._check_iteration(evaluation, path)
            return
        if not isinstance(source, dict) or not isinstance(source.get("checkpoint"), str) \
                or not isinstance(source.get("sha256"), str):
            raise ValueError(f"{path}: its 'source' must be {{checkpoint, iteration, sha256}}, got {source!r}")
        checkpoint = self.path / Path(source["checkpoint"]).name
        if checkpoint.is_file() and file_sha256(checkpoint) != source["sha256"]:
            raise ValueError(f"{path} was made from {source['checkpoint']} at iteration {source.get('iteration')}, "
                             f"but the run's {checkpoint.name} is another checkpoint now (a later or new run): "
                             f"evaluate it again (python -m aectorch.evaluate checkpoint={checkpoint} out={path} ...)")

    def _check_iteration(self, evaluation: dict, path: Path) -> None:
        """An evaluation of ``python -m aectorch.evaluate`` from before the hash was recorded names
        its checkpoint and iteration: one of another iteration than the run's file is refused."""
        name, iteration = evaluation.get("checkpoint"), evaluation.get("iteration")
        if not isinstance(name, str) or not _is_int(iteration):
            return
        checkpoint = self.path / Path(name).name
        if not checkpoint.is_file():
            return
        import torch

        try:
            held = torch.load(checkpoint, map_location="cpu", weights_only=True).get("iteration")
        except Exception:  # noqa: BLE001 - an unreadable checkpoint is its readers' to name
            return
        if _is_int(held) and held != iteration:
            raise ValueError(f"{path} was made from {checkpoint.name} at iteration {iteration}, but the run's "
                             f"{checkpoint.name} holds iteration {held} (a later or new run): evaluate it again "
                             f"(python -m aectorch.evaluate checkpoint={checkpoint} out={path} ...)")

    def per_trial(self, name: str = EVALUATION) -> list[dict]:
        """The ``per_trial`` rows of an evaluation: texture, distance, each movement's errors.

        Raises:
            KeyError: the evaluation has no ``per_trial`` rows (an older format).
        """
        return per_trial_rows(self.evaluation(name), self.path / name)


def per_trial_rows(evaluation: dict, source: str | os.PathLike = "the evaluation") -> list[dict]:
    """The ``per_trial`` rows of an evaluation's dict; ``source`` names it in the error."""
    if "per_trial" not in evaluation:
        raise KeyError(f"{source} has no per_trial rows (written by an older aectorch.evaluation?)")
    return evaluation["per_trial"]
