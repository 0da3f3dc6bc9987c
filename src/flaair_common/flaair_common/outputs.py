"""outputs: a command's outputs are never its inputs, and are checked before anything is computed.

`check_output` refuses, in one line naming `--out`, an output that would overwrite one of the
command's inputs or the project's config (config/, the model every tool reads), an existing
output without `--force`, a directory where a file is wanted and the other way round, and a
place the command cannot write. `writing_outputs` turns a failed write (disk full, a file
system turned read-only) into an `OutputError` and removes what was partly written, so a
command leaves either its whole output or none.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from flaair_model.config import ConfigError, config_dir

__all__ = ["OutputError", "check_output", "writing_outputs"]


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


@contextlib.contextmanager
def writing_outputs(out: Path, written: Sequence[Path], new_dir: bool = False) -> Iterator[None]:
    """Write a command's outputs; a failed write (or a Ctrl-C) removes them, and the directory
    `out` when `new_dir` (the command created it), then raises one-line OutputError (or the
    KeyboardInterrupt).
    """
    try:
        yield
    except (OSError, KeyboardInterrupt) as exc:
        for path in written:
            if path.is_file() and not path.is_symlink():
                with contextlib.suppress(OSError):
                    path.unlink()
        if new_dir:
            shutil.rmtree(out, ignore_errors=True)
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise OutputError(
            f"--out {out}: cannot write ({exc.strerror or exc}); no partial output left"
        ) from None
