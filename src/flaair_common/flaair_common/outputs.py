"""outputs: a command's outputs are never its inputs, and are checked before anything is computed.

`check_output` refuses, in one line naming `--out`, an output that would overwrite one of the
command's inputs or the project's config (config/, the model every tool reads), an existing
output without `--force`, a directory where a file is wanted and the other way round, and a
place the command cannot write, and an output file that is a symbolic link (an output is never
written through a link).

`writing_outputs` stages the outputs: the command writes into a temporary sibling (a hidden
directory beside or inside `--out`, or a hidden file beside the output file) and only a whole
result is renamed into place, the earlier result (`--force`) staying until then. A failed write
(disk full, a file system turned read-only), a Ctrl-C or a SIGTERM removes the stage alone, so
a command leaves either its whole new output or what was there before.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

from flaair_model.config import ConfigError, config_dir

__all__ = ["OutputError", "check_output", "write_outputs", "writing_outputs"]


class OutputError(ValueError):
    """An output path a command refuses; the message is one line naming it."""


def _resolved(path: Path) -> Path:
    return Path(os.path.realpath(path))


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _project_config() -> Path | None:
    try:
        return _resolved(config_dir())
    except ConfigError:
        return None


def check_output(
    out: Path,
    inputs: Sequence[Path | None],
    force: bool,
    files: Sequence[str] | None = None,
) -> list[Path]:
    """The paths a command will write, after checking them; raises OutputError.

    Parameters
    ----------
    out : Path
        The command's ``--out``.
    inputs : sequence of Path or None
        Every file or directory the command reads (None entries are skipped: a default).
    force : bool
        ``--force``: an existing output may be replaced.
    files : sequence of str, optional
        The names written inside the directory `out`; None: `out` is itself the output file.

    Returns
    -------
    list of Path
        The output files (`out` itself, or `out / name` for each of `files`).
    """
    directory = files is not None
    written = [out / name for name in files] if files is not None else [out]
    if directory and out.exists() and not out.is_dir():
        raise OutputError(f"--out {out}: is a file, not a directory")
    if not directory and out.is_dir():
        raise OutputError(f"--out {out}: is a directory, not a file")
    for path in written:
        if path.is_symlink():
            raise OutputError(
                f"--out {out}: {path} is a symbolic link (an output is never written through a "
                "link; remove it first)"
            )
    if any(path.exists() and not path.is_file() for path in written):
        raise OutputError(f"--out {out}: not a regular file (a device, FIFO or socket)")
    sources = [_resolved(p) for p in inputs if p is not None]
    config = _project_config()
    for path in [out, *written] if directory else written:
        target = _resolved(path)
        for source in sources:
            if target == source:
                raise OutputError(f"--out {out}: would overwrite the input {path}")
        if config is not None and _inside(target, config) and path in written:
            raise OutputError(f"--out {out}: would overwrite the project's config ({path})")
    if config is not None and directory and _resolved(out) == config:
        raise OutputError(f"--out {out}: is the project's config directory")
    existing = [path for path in written if path.exists()]
    if existing and not force:
        raise OutputError(f"--out {out}: {existing[0]} exists (--force replaces it)")
    _check_writable(out if directory else out.parent, out)
    return written


def _check_writable(folder: Path, out: Path) -> None:
    """The nearest existing folder on the way to `folder` must be a directory one can write in."""
    probe = folder.absolute()
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"--out {out}: {probe} is a file, not a directory")
    try:  # a file made and removed: os.access says yes to root on a read-only file system
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        raise OutputError(f"--out {out}: cannot write in {probe} ({exc.strerror or exc})") from None


def _interrupt(_signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def _signals_as(
    handler: Callable[[int, FrameType | None], Any], signals: Sequence[int]
) -> Iterator[None]:
    """`signals` handled by `handler` inside the block (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _made_parents(folder: Path) -> Path | None:
    """Create `folder` and its missing parents; returns the topmost one created (None: none)."""
    top = None
    probe = folder.absolute()
    while not probe.exists():
        top = probe
        probe = probe.parent
    folder.mkdir(parents=True, exist_ok=True)
    return top


def _commit(stage: Path, out: Path, file_mode: bool, into_existing: bool, done: list[bool]) -> None:
    """Rename the whole staged result into place (an output that is a link is replaced, never
    followed); a Ctrl-C or SIGTERM meanwhile is held off: the result is whole by then.
    """
    with _signals_as(lambda *_: None, (signal.SIGINT, signal.SIGTERM)):
        if file_mode or not into_existing:
            os.replace(stage, out)
        else:
            for entry in sorted(stage.iterdir()):
                target = out / entry.name
                if target.is_dir() and not target.is_symlink():
                    shutil.rmtree(target)
                os.replace(entry, target)
            stage.rmdir()
        done.append(True)


@contextlib.contextmanager
def writing_outputs(out: Path, written: Sequence[Path]) -> Iterator[Path]:
    """Stage a command's outputs; yields where to write them, renamed into `out` when whole.

    Parameters
    ----------
    out : Path
        The command's ``--out`` (a directory, or the output file when `written` is ``[out]``).
    written : sequence of Path
        The outputs, from `check_output`.

    Yields
    ------
    Path
        The stage: the directory to write the files into (in place of `out`), or the file to
        write (in place of the output file).

    Raises
    ------
    OutputError
        A write failed (one line; nothing new left, the earlier output kept).
    KeyboardInterrupt
        Ctrl-C or SIGTERM while writing (nothing new left, the earlier output kept).
    """
    file_mode = list(written) == [out]
    into_existing = not file_mode and out.is_dir()
    parent = out if into_existing else out.absolute().parent
    created: Path | None = None
    stage: Path | None = None
    done: list[bool] = []
    try:
        with _signals_as(_interrupt, (signal.SIGTERM,)):
            created = None if into_existing else _made_parents(parent)
            prefix = ".flaair-partial-" if into_existing else f".{out.name}.partial-"
            if file_mode:
                handle, name = tempfile.mkstemp(dir=parent, prefix=prefix)
                os.close(handle)
                stage = Path(name)
            else:
                stage = Path(tempfile.mkdtemp(dir=parent, prefix=prefix))
            stage.chmod((0o666 if file_mode else 0o777) & ~_umask())
            yield stage
            _commit(stage, out, file_mode, into_existing, done)
    except BaseException as exc:  # whatever ends the writing, the stage goes
        if done and isinstance(exc, KeyboardInterrupt):  # after the whole result was in place
            return
        if stage is not None and stage.is_dir() and not stage.is_symlink():
            shutil.rmtree(stage, ignore_errors=True)
        elif stage is not None:
            with contextlib.suppress(OSError):
                stage.unlink()
        if created is not None:
            shutil.rmtree(created, ignore_errors=True)
        if not isinstance(exc, OSError):
            raise
        raise OutputError(
            f"--out {out}: cannot write ({exc.strerror or exc}); no partial output left"
        ) from None


def write_outputs(
    prog: str, out: Path, written: Sequence[Path], write: Callable[[Path], object]
) -> int | None:
    """`write(stage)` inside `writing_outputs`, its failures said in one line on stderr.

    Returns None when the outputs are in place, else the exit status: 2 when the write failed,
    130 when Ctrl-C or SIGTERM came first (nothing new left, the earlier output kept either way).
    """
    try:
        with writing_outputs(out, written) as stage:
            write(stage)
    except OutputError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing written", file=sys.stderr)
        return 130
    return None
