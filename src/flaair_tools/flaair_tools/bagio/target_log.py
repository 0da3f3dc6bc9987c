"""A real-time target's log as a lab saves it: a MATLAB MAT file in Simulink's Structure-with-time
form.

MAT version 5 (MATLAB's default ``-v7``, compressed or not) is read with ``scipy.io``;
version 7.3 (HDF5) with ``h5py``, reading only the signals asked for, so memory stays near
the size of what is used. The HDF5 library is C code that a damaged file can crash
outright, so v7.3 is read in a child process (this file run as a script, ``FILE OUT.npz
LABEL...``, importing numpy and h5py only): a crash there is one more `LabFileError`, and the
import that asked loses nothing. The variable holds ``time`` (N x 1, seconds, uniform) and
``signals``, a 1 x k struct array whose elements carry ``values`` (N x 1), ``label`` and
``blockName``.

Every refusal is a `LabFileError` whose message names the file and what is wrong.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flaair_model.checked_files import CheckedFileError, check_file
from flaair_tools.bagio import mat_bounds

__all__ = ["UNIFORM_TOLERANCE", "LabFileError", "TargetLog", "read_target_log"]

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


def read_target_log(path: Path | str, labels: Sequence[str]) -> TargetLog:
    """The run logged in `path`, with the values of `labels` (the rig's signal labels).

    Raises
    ------
    LabFileError
        Not a MAT file (v5 or v7.3), unreadable or cut short, no Structure-with-time variable, a
        label the rig names but the log lacks, values not as long as time, non-uniform time.
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
    if head.startswith(_V5_HEADER):
        variable, time_s, found, raw = _read_v5(path, labels)
    elif head.startswith(_HDF5_SIGNATURE) or _is_hdf5(path):
        variable, time_s, found, raw = _read_v73_in_child(path, labels)
    else:
        raise LabFileError(f"{path}: not a MATLAB MAT file (version 5 or 7.3)")
    return _checked(path, variable, time_s, found, raw, labels)


def _checked(
    path: Path,
    variable: str,
    time_s: np.ndarray,
    all_labels: tuple[str, ...],
    values: dict[str, np.ndarray],
    wanted: Sequence[str],
) -> TargetLog:
    where = f"{path}: variable '{variable}'"
    missing = [label for label in wanted if label not in values]
    if missing:
        raise LabFileError(
            f"{where}: no signal labelled {', '.join(map(repr, missing))} "
            f"(the log holds: {', '.join(map(repr, all_labels)) or 'no labels'})"
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
    for label, v in values.items():
        if v.size != time_s.size:
            raise LabFileError(
                f"{where}: signal '{label}' has {v.size} values, time has {time_s.size}"
            )
        if not np.isfinite(v).all():  # as the CSV import refuses them
            raise LabFileError(
                f"{where}: signal '{label}' value {int(np.argmin(np.isfinite(v)))} is not finite"
            )
    return TargetLog(path, variable, time_s, {label: values[label] for label in wanted}, all_labels)


def _read_v5(
    path: Path, wanted: Sequence[str]
) -> tuple[str, np.ndarray, tuple[str, ...], dict[str, np.ndarray]]:
    import scipy.io

    try:
        variables = scipy.io.whosmat(str(path))
    except Exception as exc:
        raise LabFileError(
            f"{path}: not a readable MAT v5 file ({type(exc).__name__}: {exc})"
        ) from None
    for name, _shape, kind in variables:
        if kind != "struct":
            continue
        try:
            data = scipy.io.loadmat(
                str(path),
                variable_names=[name],
                squeeze_me=False,
                struct_as_record=False,
                chars_as_strings=True,
            )
        except Exception as exc:
            raise LabFileError(
                f"{path}: variable '{name}' cannot be read ({type(exc).__name__}: {exc})"
            ) from None
        log = data[name].reshape(-1)[0]
        fields = set(getattr(log, "_fieldnames", ()))
        if not {"time", "signals"} <= fields:
            continue
        signals = np.asarray(log.signals).reshape(-1)
        if not signals.size or not {"values", "label"} <= set(
            getattr(signals[0], "_fieldnames", ())
        ):
            continue
        labels = tuple(_v5_text(s.label) for s in signals)
        try:  # a char or struct field is no signal
            values = {
                label: np.asarray(s.values, dtype=float).reshape(-1)
                for label, s in zip(labels, signals, strict=True)
                if label in wanted
            }
            return name, np.asarray(log.time, dtype=float), labels, values
        except (TypeError, ValueError):
            raise LabFileError(
                f"{path}: variable '{name}': time or a signal's values are not numbers"
            ) from None
    raise LabFileError(
        f"{path}: no variable in Structure-with-time form (a struct with 'time' and "
        "'signals' whose elements have 'values' and 'label'); variables: "
        f"{', '.join(name for name, _, _ in variables) or 'none'}"
    )


def _v5_text(value: Any) -> str:
    array = np.asarray(value).reshape(-1)
    return "".join(str(v) for v in array) if array.size else ""


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
    path: Path, wanted: Sequence[str]
) -> tuple[str, np.ndarray, tuple[str, ...], dict[str, np.ndarray]]:
    """`_read_v73` in a child process; its refusal, crash or hang becomes a LabFileError."""
    with tempfile.TemporaryDirectory(prefix="flaair-mat-") as tmp:
        out = Path(tmp) / "log.npz"
        try:
            done = subprocess.run(
                [sys.executable, __file__, str(path), str(out), *wanted],
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
            values = {label: arrays[f"value_{k}"] for k, label in enumerate(head["found"])}
            return head["variable"], arrays["time"], tuple(head["labels"]), values


def _read_v73(
    path: Path, wanted: Sequence[str]
) -> tuple[str, np.ndarray, tuple[str, ...], dict[str, np.ndarray]]:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            names = [name for name in f if not name.startswith("#")]
            for name in names:
                group = f[name]
                if not (
                    isinstance(group, h5py.Group)
                    and _matlab_class(group) == "struct"
                    and "time" in group
                    and "signals" in group
                ):
                    continue
                signals = group["signals"]
                if not (
                    isinstance(signals, h5py.Group) and "values" in signals and "label" in signals
                ):
                    continue
                labels = tuple(_h5_text(f, item) for item in _elements(signals["label"]))
                values = {
                    label: np.asarray(_h5_deref(f, item), dtype=float).reshape(-1)
                    for label, item in zip(labels, _elements(signals["values"]), strict=False)
                    if label in wanted
                }
                return name, np.asarray(_h5_deref(f, group["time"]), dtype=float), labels, values
    except LabFileError:
        raise
    except Exception as exc:
        raise LabFileError(
            f"{path}: not a readable MAT v7.3 file ({type(exc).__name__}: {exc})"
        ) from None
    raise LabFileError(
        f"{path}: no variable in Structure-with-time form (a struct with 'time' and "
        "'signals' whose elements have 'values' and 'label'); variables: "
        f"{', '.join(names) or 'none'}"
    )


def _matlab_class(obj: Any) -> str:
    value = obj.attrs.get("MATLAB_class", b"")
    return value.decode() if isinstance(value, bytes) else str(value)


def _elements(dataset: Any) -> list[Any]:
    """The elements of a struct-array field: object
    references (k > 1), or the dataset itself (k = 1).
    """
    data = dataset[()]
    if getattr(data, "dtype", None) is not None and data.dtype.kind == "O":
        return list(np.asarray(data).reshape(-1))
    return [dataset]


def _dataset(f: Any, item: Any) -> Any:
    """`item` itself when a dataset, else the dataset its object reference points to."""
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
    path, out, wanted = Path(argv[0]), Path(argv[1]), argv[2:]
    try:
        variable, time_s, labels, values = _read_v73(path, wanted)
    except LabFileError as exc:
        print(exc, file=sys.stderr)
        return 2
    found = list(values)
    np.savez(out, time=time_s, **{f"value_{k}": values[label] for k, label in enumerate(found)})
    print(json.dumps({"variable": variable, "labels": list(labels), "found": found}))
    return 0


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1:]))
