"""A real-time target's log as a lab saves it: a MATLAB MAT file in Simulink's Structure-with-time
form.

MAT version 5 (MATLAB's default ``-v7``, compressed or not) is read element by element
(`flaair_tools.bagio.mat_v5`), version 7.3 (HDF5) with ``h5py``: in both only the log variable
is read, and of its signals only the values asked for are kept, so memory stays near the size
of what is used and whatever else the file holds (MATLAB objects, other variables) does not
matter. The HDF5 library is C code that a damaged file can crash outright, so v7.3 is read in
a child process (this file run as a script, ``FILE OUT.npz VARIABLE LABEL...``, importing
numpy and h5py only): a crash there is one more `LabFileError`, and the import that asked
loses nothing. The variable holds ``time`` (N x 1, seconds, uniform) and ``signals``, a 1 x k
struct array whose elements carry ``values`` (N x 1, or N x k for a Scope with several
inputs), ``label`` and often ``blockName`` or ``title``. The rig's ``log_variable`` names the
variable when the file holds several in this form; ``"label[j]"`` names column j (from 1).

Every refusal is a `LabFileError` whose message names the file and what is wrong.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flaair_model.checked_files import CheckedFileError, check_file
from flaair_tools.bagio import mat_bounds, mat_v5

__all__ = [
    "COLUMN_LABEL",
    "UNIFORM_TOLERANCE",
    "LabFileError",
    "TargetLog",
    "read_target_log",
    "split_label",
]

# a rig's name for one column of an N x k signal: "label[j]", j counted from 1
COLUMN_LABEL = re.compile(r"(.+)\[([1-9][0-9]*)\]")
# Relative spread of the time steps still called uniform (float rounding of k / fs).
UNIFORM_TOLERANCE = 1e-6
_V5_HEADER = b"MATLAB 5.0 MAT-file"
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
# the child reading a v7.3 file: generous for a long log on a loaded machine
V73_READ_TIMEOUT_S = 300.0


class LabFileError(ValueError):
    """A lab file that cannot be imported; the message names the file and what is wrong."""


@dataclass(frozen=True)
class TargetLog:
    """The signals of one logged run.

    Attributes
    ----------
    path : the MAT file.
    variable : the Structure-with-time variable's name.
    time_s : (N,) sample times.
    signals : label -> (N,) values, for the labels asked for.
    labels : every label the log holds, in its order.
    """

    path: Path
    variable: str
    time_s: np.ndarray
    signals: dict[str, np.ndarray]
    labels: tuple[str, ...]

    @property
    def sample_rate_hz(self) -> float:
        """The log's sample rate (its time steps are uniform)."""
        return float((self.time_s.size - 1) / (self.time_s[-1] - self.time_s[0]))


def split_label(text: str) -> tuple[str, int | None]:
    """A rig's signal name as (label, column): ``"pvdf[2]"`` is column 2 (from 1) of ``pvdf``."""
    match = COLUMN_LABEL.fullmatch(text)
    if match is None:
        return text, None
    return match.group(1), int(match.group(2))


@dataclass(frozen=True)
class _Signal:
    """One element of the log's signals: its label, where it came from, its values (N x k)."""

    label: str
    origin: str  # "blockName 'x'" or "title 'x'" when the element has one, else ""
    values: np.ndarray | None  # MATLAB's shape; None when not asked for


def read_target_log(
    path: Path | str, labels: Sequence[str], variable: str | None = None
) -> TargetLog:
    """The run logged in `path`, with the values of `labels` (the rig's signal labels).

    A label may name one column of an N x k signal as ``"label[j]"`` (j from 1). `variable`
    names the log (the rig's ``log_variable``); without it the file must hold exactly one
    variable in Structure-with-time form. Only that variable is read, and of its signals only
    the values of those asked for are kept.

    Raises
    ------
    LabFileError
        Not a MAT file (v5 or v7.3), unreadable or cut short, no Structure-with-time variable
        (or several and no `variable`), a label the rig names but the log lacks or that two
        signals share, an N x k signal named without a column, values not as long as time,
        non-uniform time.
    """
    path = Path(path)
    try:  # a regular file, bounded; compressed data bounded before it is read
        with open(check_file(path, "mat"), "rb") as handle:
            head = handle.read(128)
        if head.startswith(_V5_HEADER):
            mat_bounds.check_v5(path)
    except OSError as exc:
        raise LabFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (CheckedFileError, mat_bounds.MatBoundsError) as exc:
        raise LabFileError(str(exc)) from None
    bases = sorted({split_label(label)[0] for label in labels})
    if head.startswith(_V5_HEADER):
        name, time_s, signals = _read_v5(path, bases, variable)
    elif head.startswith(_HDF5_SIGNATURE) or _is_hdf5(path):
        name, time_s, signals = _read_v73_in_child(path, bases, variable)
    else:
        raise LabFileError(f"{path}: not a MATLAB MAT file (version 5 or 7.3)")
    return _checked(path, name, time_s, signals, labels)


def _listed(names: Sequence[str]) -> str:
    """At most the first ten of `names`, quoted."""
    shown = ", ".join(map(repr, names[:10]))
    return f"{shown}, ... ({len(names)} in all)" if len(names) > 10 else shown or "none"


def _choose(path: Path, candidates: list[str], names: list[str], variable: str | None) -> str:
    """The log variable: the rig's `variable`, else the one Structure-with-time candidate."""
    if variable is not None:
        if variable not in names:
            raise LabFileError(
                f"{path}: no variable {variable!r} (log_variable); the file holds {_listed(names)}"
            )
        if variable not in candidates:
            raise LabFileError(
                f"{path}: variable {variable!r} (log_variable) is not in Structure-with-time "
                "form (a struct with 'time' and 'signals')"
            )
        return variable
    if len(candidates) > 1:
        raise LabFileError(
            f"{path}: {len(candidates)} variables in Structure-with-time form "
            f"({_listed(candidates)}): name the log in the rig file (log_variable)"
        )
    if not candidates:
        raise LabFileError(
            f"{path}: no variable in Structure-with-time form (a struct with 'time' and "
            f"'signals' whose elements have 'values' and 'label'); variables: {_listed(names)}"
        )
    return candidates[0]


def _not_the_form(path: Path, name: str) -> LabFileError:
    return LabFileError(
        f"{path}: variable '{name}' is not in Structure-with-time form ('time' numbers and "
        "'signals' a struct array whose elements have 'values' and 'label')"
    )


def _matrix(values: np.ndarray) -> np.ndarray:
    """Values as MATLAB's N x k (a 1 x N row taken as N x 1)."""
    values = np.asarray(values, dtype=float)
    if values.ndim != 2:
        values = values.reshape(values.shape[0] if values.ndim else 1, -1)
    return values.T if values.shape[0] == 1 and values.shape[1] > 1 else values


def _checked(
    path: Path,
    variable: str,
    time_s: np.ndarray,
    signals: list[_Signal],
    wanted: Sequence[str],
) -> TargetLog:
    where = f"{path}: variable '{variable}'"
    all_labels = tuple(s.label for s in signals)
    missing = [text for text in wanted if split_label(text)[0] not in all_labels]
    if missing:
        raise LabFileError(
            f"{where}: no signal labelled {', '.join(map(repr, missing))} "
            f"(the log holds: {_listed(all_labels) if all_labels else 'no labels'})"
        )
    time_s = np.asarray(time_s, dtype=float).reshape(-1)
    if time_s.size < 2 or not np.isfinite(time_s).all():
        raise LabFileError(f"{where}: time must hold at least 2 finite samples, has {time_s.size}")
    steps = np.diff(time_s)
    step = float(np.median(steps))
    if not step > 0 or np.max(np.abs(steps - step)) > UNIFORM_TOLERANCE * step:
        raise LabFileError(
            f"{where}: time is not uniform (steps from {steps.min():.6g} to {steps.max():.6g} s)"
        )
    out = {}
    for text in wanted:
        label, column = split_label(text)
        matches = [k for k, s in enumerate(signals) if s.label == label]
        if len(matches) > 1:
            origins = [signals[k].origin for k in matches if signals[k].origin]
            raise LabFileError(
                f"{where}: {len(matches)} signals are labelled {label!r}: signals "
                f"{', '.join(str(k + 1) for k in matches)}"
                + (f" ({', '.join(origins)})" if origins else "")
                + "; give each signal its own label in the model"
            )
        values = signals[matches[0]].values
        assert values is not None
        values = _matrix(values)
        rows, columns = values.shape
        if rows != time_s.size:
            raise LabFileError(
                f"{where}: signal '{label}' has {rows} values, time has {time_s.size}"
            )
        if column is None and columns > 1:
            raise LabFileError(
                f"{where}: signal '{label}' has {columns} columns (a Scope with several "
                f"inputs): name one as '{label}[j]', j from 1 to {columns}"
            )
        if column is not None and not 1 <= column <= columns:
            raise LabFileError(
                f"{where}: {text!r}: signal '{label}' has {columns} column(s), counted from 1"
            )
        chosen = np.ascontiguousarray(values[:, (column or 1) - 1])
        if not np.isfinite(chosen).all():  # as the CSV import refuses them
            first = int(np.argmin(np.isfinite(chosen)))
            raise LabFileError(f"{where}: signal {text!r} value {first} is not finite")
        out[text] = chosen
    return TargetLog(path, variable, time_s, out, all_labels)


def _origin(fields: dict[str, Any]) -> str:
    for key in ("blockName", "title"):
        if isinstance(fields.get(key), str) and fields[key]:
            return f"{key} {fields[key]!r}"
    return ""


def _read_v5(
    path: Path, bases: Sequence[str], variable: str | None
) -> tuple[str, np.ndarray, list[_Signal]]:
    def lighten(fields: dict[str, Any]) -> dict[str, Any]:
        # a signal not asked for: dropped as soon as its element is read
        if isinstance(fields.get("label"), str) and fields["label"] not in bases:
            fields["values"] = None
        return fields

    try:
        with open(path, "rb") as handle:
            variables = mat_v5.list_variables(handle)
            candidates = [
                v.name
                for v in variables
                if v.matlab_class == "struct" and {"time", "signals"} <= set(v.fields)
            ]
            name = _choose(path, candidates, [v.name for v in variables], variable)
            chosen = next(v for v in variables if v.name == name)
            value = mat_v5.read_variable(handle, chosen, lighten)
    except mat_v5.MatV5Error as exc:
        raise LabFileError(f"{path}: not a readable MAT v5 file ({exc})") from None
    except OSError as exc:
        raise LabFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    log = value[0] if isinstance(value, list) and value else {}
    time_s, elements = log.get("time"), log.get("signals")
    if not (
        isinstance(time_s, np.ndarray)
        and isinstance(elements, list)
        and elements
        and all(
            isinstance(e.get("label"), str)
            and isinstance(e.get("values"), (np.ndarray, type(None)))
            for e in elements
        )
    ):
        raise _not_the_form(path, name)
    signals = [_Signal(e["label"], _origin(e), e["values"]) for e in elements]
    return name, time_s, signals


def _is_hdf5(path: Path) -> bool:
    """An HDF5 signature at 0, 512, 1024, ... (MATLAB v7.3 puts a 512-byte text header first)."""
    with open(path, "rb") as handle:
        offset = 512
        while True:
            handle.seek(offset)
            block = handle.read(8)
            if len(block) < 8:
                return False
            if block == _HDF5_SIGNATURE:
                return True
            offset *= 2


def _read_v73_in_child(
    path: Path, bases: Sequence[str], variable: str | None
) -> tuple[str, np.ndarray, list[_Signal]]:
    """`_read_v73` in a child process; its refusal, crash or hang becomes a LabFileError."""
    with tempfile.TemporaryDirectory(prefix="flaair-mat-") as tmp:
        out = Path(tmp) / "log.npz"
        try:
            done = subprocess.run(
                [sys.executable, __file__, str(path), str(out), variable or "", *bases],
                capture_output=True,
                text=True,
                timeout=V73_READ_TIMEOUT_S,
            )
        except subprocess.TimeoutExpired:
            raise LabFileError(
                f"{path}: reading the MAT v7.3 file took over "
                f"{V73_READ_TIMEOUT_S:g} s; is it damaged?"
            ) from None
        if done.returncode == 2 and done.stderr.strip():
            raise LabFileError(done.stderr.strip().splitlines()[-1])
        if done.returncode != 0:
            how = f"signal {-done.returncode}" if done.returncode < 0 else f"exit {done.returncode}"
            raise LabFileError(
                f"{path}: not a readable MAT v7.3 file (the HDF5 reader died: {how})"
            )
        head = json.loads(done.stdout)
        with np.load(out) as arrays:
            signals = [
                _Signal(label, origin, arrays.get(f"value_{k}"))
                for k, (label, origin) in enumerate(
                    zip(head["labels"], head["origins"], strict=True)
                )
            ]
            return head["variable"], arrays["time"], signals


def _read_v73(
    path: Path, bases: Sequence[str], variable: str | None
) -> tuple[str, np.ndarray, list[_Signal]]:
    # deferred: h5py (60 ms, the HDF5 C library) is for v7.3 files, read in a child process
    import h5py

    try:
        with h5py.File(path, "r") as f:
            names = [name for name in f if not name.startswith("#")]
            candidates = [
                name
                for name in names
                if isinstance(f[name], h5py.Group)
                and _matlab_class(f[name]) == "struct"
                and "time" in f[name]
                and "signals" in f[name]
            ]
            name = _choose(path, candidates, names, variable)
            group = f[name]
            signals = group["signals"]
            if not (isinstance(signals, h5py.Group) and "values" in signals and "label" in signals):
                raise _not_the_form(path, name)
            labels = [_h5_text(f, item) for item in _elements(signals["label"])]
            origins = [""] * len(labels)
            for key in ("title", "blockName"):
                if key in signals:
                    items = _elements(signals[key])
                    texts = [_h5_text(f, item) for item in items]
                    if len(texts) == len(labels):
                        origins = [
                            f"{key} {text!r}" if text else old
                            for text, old in zip(texts, origins, strict=True)
                        ]
            values = _elements(signals["values"])
            if len(values) != len(labels):
                raise _not_the_form(path, name)
            out = [
                _Signal(
                    label,
                    origin,
                    np.asarray(_h5_deref(f, item), dtype=float).T if label in bases else None,
                )
                for label, origin, item in zip(labels, origins, values, strict=True)
            ]
            return name, np.asarray(_h5_deref(f, group["time"]), dtype=float), out
    except LabFileError:
        raise
    except Exception as exc:
        raise LabFileError(
            f"{path}: not a readable MAT v7.3 file ({type(exc).__name__}: {exc})"
        ) from None


def _matlab_class(obj: Any) -> str:
    value = obj.attrs.get("MATLAB_class", b"")
    return value.decode() if isinstance(value, bytes) else str(value)


def _elements(dataset: Any) -> list[Any]:
    """The elements of a struct-array field: object
    references (k > 1), or the dataset itself (k = 1).
    """
    # deferred: h5py is for v7.3 files, read in a child process (`_read_v73`)
    import h5py

    if h5py.check_dtype(ref=dataset.dtype) is not None:
        return list(np.asarray(dataset[()]).reshape(-1))
    return [dataset]


def _dataset(f: Any, item: Any) -> Any:
    """`item` itself when a dataset, else the dataset its object reference points to."""
    # deferred: h5py is for v7.3 files, read in a child process (`_read_v73`)
    import h5py

    return item if isinstance(item, h5py.Dataset) else f[item]


def _h5_deref(f: Any, item: Any) -> np.ndarray:
    dataset = _dataset(f, item)
    try:
        mat_bounds.check_dataset(Path(f.filename), dataset)
    except mat_bounds.MatBoundsError as exc:
        raise LabFileError(str(exc)) from None
    return np.asarray(dataset[()])


def _h5_text(f: Any, item: Any) -> str:
    dataset = _dataset(f, item)
    if _matlab_class(dataset) != "char":
        raise LabFileError(
            f"{f.filename}: a signal label is not text (MATLAB class {_matlab_class(dataset)!r})"
        )
    if dataset.attrs.get("MATLAB_empty", 0):
        return ""
    return "".join(chr(int(c)) for c in np.asarray(dataset[()]).reshape(-1))


def _child_main(argv: list[str]) -> int:
    """Child side of `_read_v73_in_child`: read, save the arrays to OUT.npz, JSON on stdout."""
    path, out, variable, bases = Path(argv[0]), Path(argv[1]), argv[2] or None, argv[3:]
    try:
        name, time_s, signals = _read_v73(path, bases, variable)
    except LabFileError as exc:
        print(exc, file=sys.stderr)
        return 2
    kept = {f"value_{k}": s.values for k, s in enumerate(signals) if s.values is not None}
    np.savez(out, time=time_s, **kept)
    head = {
        "variable": name,
        "labels": [s.label for s in signals],
        "origins": [s.origin for s in signals],
    }
    print(json.dumps(head))
    return 0


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1:]))
