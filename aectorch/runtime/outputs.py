"""The run folder's files: config.yaml, provenance.json, metrics.jsonl, tb/ and summary.json."""

from __future__ import annotations

import fcntl
import json
import math
import os
import tempfile
from pathlib import Path
from typing import IO, Any

__all__ = ["CODE_AT_ENDS", "CODE_READOUTS", "FIGURE_FILES", "LOCK_NAME", "OUTPUTS_LIST", "RUN_FILES", "RunFolder", "RunFolderBusy",
           "WriteFailed", "atomic_write", "format_summary", "json_value", "note_output", "write_json"]

#: The file in a run folder whose lock (``flock``) the training process holds.
LOCK_NAME = ".lock"

#: The code's read-outs at the perturbation events' ends (`aectorch.runtime.loop.Perturbations`),
#: which ``summary.json`` reports.
CODE_AT_ENDS = "code_at_event_ends.json"

#: The code's read-outs every ``train.readout_every`` iterations and at the end
#: (`aectorch.runtime.loop.CodeReadouts`): one JSON line each, ``{"iteration": N, "code":
#: {"<cue>/<scale>": code_summary}}``; a resume keeps the lines up to its checkpoint's iteration.
CODE_READOUTS = "code_readouts.jsonl"

#: The figures a run draws into its ``figures/`` folder (`aectorch.runtime.finish`).
FIGURE_FILES = ("dictionaries.png", "training.png", "code.png", "perturbation.png", "evaluation.png")

#: The file in a run folder that lists what the commands beside ``train.py`` wrote into it (an
#: evaluation's JSON and figure: `note_output`), so that ``train.overwrite`` deletes them too.
OUTPUTS_LIST = ".aectorch_outputs.json"

#: What a run writes into its folder. ``train.overwrite=true`` deletes these, the figures of
#: :data:`FIGURE_FILES` in ``figures/``, TensorBoard's event files in ``tb/`` (each folder when
#: nothing else is left in it) and what :data:`OUTPUTS_LIST` names, and nothing else: a user's own
#: file stays, and Hydra's ``.hydra/`` and ``train.log`` are Hydra's.
RUN_FILES = ("checkpoint.pt", "best.pt", "calibrated.pt", "metrics.jsonl", "provenance.json", "config.yaml",
             "summary.json", "evaluation.json", "tb", "figures", CODE_AT_ENDS, CODE_READOUTS)

#: The folders among :data:`RUN_FILES` and the files in them that a run writes.
_RUN_FOLDERS = {"figures": lambda name: name in FIGURE_FILES, "tb": lambda name: name.startswith("events.out.tfevents.")}


def note_output(path: str | os.PathLike) -> None:
    """Record that an aectorch command wrote ``path``, when it lies in a run folder (beside a
    ``checkpoint.pt``): a later ``train.overwrite=true`` there deletes it with the run's files."""
    path = Path(path)
    folder = path.resolve().parent
    if not (folder / "checkpoint.pt").is_file() or path.name in RUN_FILES:
        return
    listed = _outputs_listed(folder)
    if path.name not in listed:
        write_json(folder / OUTPUTS_LIST, {"files": listed + [path.name]})


def _outputs_listed(folder: Path) -> list[str]:
    try:
        files = json.loads((folder / OUTPUTS_LIST).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    # Plain names only: the list never reaches outside its folder.
    return [name for name in files if isinstance(name, str) and name and "/" not in name and name not in (".", "..")]


class RunFolderBusy(ValueError):
    """Another process trains in this run folder."""


_UMASK = os.umask(0)
os.umask(_UMASK)


class WriteFailed(OSError):
    """A file of the run could not be written (the disk is full, a file-size limit, ...); the
    message names it and says that the previous version is as it was."""


def atomic_write(path: str | os.PathLike, write, *, binary: bool = False) -> None:
    """Write ``path`` whole or not at all: ``write(file)`` fills a temporary file beside it, which
    is flushed, fsynced and then renamed over ``path``. If anything fails the temporary file is
    removed, ``path`` keeps its previous content, and `WriteFailed` names it."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # what open() would give (mkstemp's file is private)
        with os.fdopen(fd, "wb" if binary else "w") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(err, (OSError, RuntimeError)):  # torch.save reports a short write as a RuntimeError
            reason = os.strerror(err.errno) if isinstance(err, OSError) and err.errno else str(err).splitlines()[0]
            raise WriteFailed(f"cannot write {path}: {reason} (is the disk full, or a file-size limit set?); "
                              f"{path.name} is as it was before") from err
        raise


def json_value(value):
    """``value`` as JSON can hold it: NaN becomes null, infinities stay (``allow_nan``)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else value
    return value


def write_json(path: str | os.PathLike, data: dict) -> None:
    """Write ``data`` as JSON, whole or not at all (`atomic_write`)."""
    text = json.dumps(data, indent=2, allow_nan=True) + "\n"
    atomic_write(path, lambda f: f.write(text))


def _quiet_tensorboard_thread() -> None:
    """TensorBoard's writer thread prints a traceback when a write fails; `RunFolder.log_line`
    raises the same error (`WriteFailed`, one line) from its flush, so the thread's is not printed."""
    import threading

    hook = threading.excepthook
    if getattr(hook, "_aectorch", False):
        return

    def excepthook(args):
        if type(args.thread).__name__ == "_AsyncWriterThread" and issubclass(args.exc_type, OSError):
            return
        hook(args)

    excepthook._aectorch = True  # type: ignore[attr-defined]
    threading.excepthook = excepthook


def _keep_lines_until(path: Path, iteration: int) -> None:
    """Keep the lines of a JSON-lines run file (``{"iteration": ...}`` each) up to ``iteration``
    (a resume's checkpoint), replacing the file whole or not at all (`atomic_write`): an
    interrupted resume loses no earlier line. A line torn by a kill mid-write is dropped."""
    if not path.exists():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # only the last line can be torn, and it is after the checkpoint
        if record["iteration"] <= iteration:
            kept.append(line)
    atomic_write(path, lambda f: f.write("".join(line + "\n" for line in kept)))


class RunFolder:
    """The files a run writes into its folder; only the main process (rank 0) writes.

    Args:
        path: the run folder (created).
        main: whether this process writes; the others' metrics go to ``os.devnull``.
    """

    def __init__(self, path: str | Path, main: bool = True) -> None:
        self.path, self.main = Path(path), main
        self._lock: IO[str] | None = None
        if main:
            self.path.mkdir(parents=True, exist_ok=True)
            self._acquire()
        self.metrics_path = self.path / "metrics.jsonl"
        self.readouts_path = self.path / CODE_READOUTS
        self._writer: Any = None  # tensorboard's SummaryWriter once started

    @staticmethod
    def _busy(path: Path, holder: str) -> RunFolderBusy:
        return RunFolderBusy(f"run folder {str(path)!r} is in use by process {holder} (another train.py "
                             f"trains there); wait for it to end, or choose another hydra.run.dir")

    @classmethod
    def check_free(cls, path: str | os.PathLike) -> None:
        """`RunFolderBusy` if a process holds ``path``'s lock; writes nothing (``train.py`` asks
        before Hydra writes into the folder)."""
        lock_path = Path(path) / LOCK_NAME
        try:
            lock = lock_path.open("r")
        except OSError:  # no lock file: never trained in, or not readable (then _acquire reports it)
            return
        with lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise cls._busy(Path(path), lock.read().strip() or "unknown") from None
            fcntl.flock(lock, fcntl.LOCK_UN)

    def _acquire(self) -> None:
        """Hold the folder's lock for this process: a second run into the same folder (a new run
        or ``train.resume``) is refused at once, naming the process that trains there. The lock is
        the kernel's (``flock``): it ends with its process, so a holder killed with -9 keeps
        nothing locked."""
        lock = (self.path / LOCK_NAME).open("a+")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.seek(0)
            holder = lock.read().strip() or "unknown"
            lock.close()
            raise self._busy(self.path, holder) from None
        lock.seek(0)
        lock.truncate()
        lock.write(f"{os.getpid()}\n")
        lock.flush()
        self._lock = lock

    def clear(self) -> list[str]:
        """Delete the files of the run this folder holds, under the folder's lock
        (``train.overwrite``): :data:`RUN_FILES`, the run's own files in ``figures/`` and ``tb/``,
        and the outputs listed in :data:`OUTPUTS_LIST`; nothing else. Returns the names deleted."""
        if self._lock is None:
            raise RuntimeError("RunFolder.clear needs the folder's lock (the main process's RunFolder)")
        deleted = []
        for name in (*RUN_FILES, *_outputs_listed(self.path), OUTPUTS_LIST):
            path = self.path / name
            if name in _RUN_FOLDERS and path.is_dir() and not path.is_symlink():
                ours = [p for p in path.iterdir() if _RUN_FOLDERS[name](p.name) and (p.is_file() or p.is_symlink())]
                for p in ours:
                    p.unlink()
                deleted += [f"{name}/{p.name}" for p in ours]
                if not any(path.iterdir()):
                    path.rmdir()
            elif path.is_file() or path.is_symlink():
                path.unlink()
                deleted.append(name)
        return deleted

    def release(self) -> None:
        """Let other runs into the folder (at the run's end; the process's end does it too)."""
        if self._lock is not None:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()
            self._lock = None

    def __truediv__(self, name: str) -> Path:
        return self.path / name

    def start(self, config: dict, session: dict, *, resumed_at: int | None, tensorboard: bool) -> None:
        """Write config.yaml and provenance.json (a resume adds its session), start metrics.jsonl
        and :data:`CODE_READOUTS` (a resume keeps their lines up to its checkpoint's iteration) and
        TensorBoard."""
        if not self.main:
            return
        from omegaconf import OmegaConf

        (self.path / "config.yaml").write_text(OmegaConf.to_yaml(OmegaConf.create(config)))
        provenance_path = self.path / "provenance.json"
        sessions = json.loads(provenance_path.read_text())["sessions"] if resumed_at is not None \
            and provenance_path.exists() else []
        write_json(provenance_path, {"sessions": sessions + [session]})
        if resumed_at is None:
            self.metrics_path.write_text("")
            self.readouts_path.unlink(missing_ok=True)
        else:
            for path in (self.metrics_path, self.readouts_path):
                _keep_lines_until(path, resumed_at)
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            _quiet_tensorboard_thread()
            self._writer = SummaryWriter(log_dir=str(self.path / "tb"), purge_step=None if resumed_at is None else resumed_at + 1)

    def open_metrics(self):
        """The metrics.jsonl file, open for appending (``os.devnull`` on other ranks)."""
        return (self.metrics_path if self.main else Path(os.devnull)).open("a")

    def log_line(self, file, line: dict) -> None:
        """Append one metrics line (and its scalars to TensorBoard). A failed write raises
        `WriteFailed`; a torn last line is dropped on resume (`RunFolder` keeps whole lines)."""
        try:
            file.write(json.dumps({k: json_value(v) for k, v in line.items()}) + "\n")
            file.flush()
        except OSError as err:
            raise WriteFailed(f"cannot write {self.metrics_path}: {os.strerror(err.errno) if err.errno else err} "
                              "(is the disk full, or a file-size limit set?); a resume keeps its whole lines") from err
        if self._writer is not None:
            try:
                for key, value in line.items():
                    if key != "iteration" and isinstance(value, (int, float)) and math.isfinite(value):
                        self._writer.add_scalar(key, value, line["iteration"])
                # TensorBoard writes in a thread; flushing here raises its failure in this one.
                self._writer.flush()
            except OSError as err:
                self._writer = None  # closing it would only raise the same error again
                raise WriteFailed(f"cannot write {self.path / 'tb'}: {os.strerror(err.errno) if err.errno else err} "
                                  "(is the disk full, or a file-size limit set?); a resume drops TensorBoard's "
                                  "events after its checkpoint") from err

    def close(self) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            try:
                writer.close()
            except OSError:
                pass  # every line was flushed by log_line, which raised any failure then

    def write_json(self, name: str, data: dict) -> None:
        write_json(self.path / name, data)

    def append_readout(self, line: dict) -> None:
        """Append one line to :data:`CODE_READOUTS` (main process only); a failed write raises
        `WriteFailed` (a torn last line is dropped on resume)."""
        if not self.main:
            return
        try:
            with self.readouts_path.open("a") as file:
                file.write(json.dumps(line, allow_nan=True) + "\n")
        except OSError as err:
            raise WriteFailed(f"cannot write {self.readouts_path}: {os.strerror(err.errno) if err.errno else err} "
                              "(is the disk full, or a file-size limit set?); a resume keeps its whole lines") from err


def format_summary(summary: dict, run_dir: Path) -> str:
    """The table ``train.py`` prints at the end: the training window's and the evaluation's MAEs."""
    def fmt(v):
        return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"

    final, evaluation = summary["final"], summary.get("evaluation", {})
    rows = [("", "training (window)", "evaluation")]
    for key in [k for k in final if k.endswith(("_mae_deg", "_mae_m"))]:
        rows.append((key, fmt(final.get(key)), fmt(evaluation.get(key))))
    lines = [f"{a:<18}{b:>18}{c:>14}" for a, b, c in rows]
    rate = summary["iterations_per_s"]
    lines.append(f"{summary['iterations']} iterations in {summary['train_seconds']:.1f} s"
                 + (f" ({rate:.2f} it/s)" if rate else "") + f"; run folder: {run_dir}")
    return "\n".join(lines)
