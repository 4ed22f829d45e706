"""CSV input for the analysis: one file ``time,reference,device`` or two files.

Strict: every problem is a ``DataError`` naming the file, the line (1-based, as an editor
shows it) or the column, the value, and what was expected. Times in seconds; angles in degrees
or radians (converted to degrees).
"""

from __future__ import annotations

import csv
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from benchctl.errors import DataError

FloatArray = NDArray[np.float64]
Units = Literal["deg", "rad"]


@dataclass(frozen=True)
class Streams:
    """Reference and device series, s and deg, with a label of where they came from."""

    t_ref: FloatArray
    x_ref: FloatArray
    t_dev: FloatArray
    y_dev: FloatArray
    source: str


def _header(path: Path) -> list[str]:
    try:
        with path.open(encoding="utf-8-sig", newline="") as f:
            first = f.readline()
    except OSError as e:
        raise DataError(f"{path}: cannot read: {e.strerror}") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a UTF-8 text CSV file") from None
    if not first.strip():
        raise DataError(f"{path}: empty file; expected a header line with column names")
    return [c.strip().strip('"') for c in next(csv.reader([first]))]


def _find(path: Path, header: list[str], name: str, option: str) -> int:
    if name not in header:
        raise DataError(
            f"{path}: no column {name!r}; the header has {header}; "
            f"name the column with {option}"
        )
    return header.index(name)


def _locate_bad(path: Path, header: list[str], cols: Sequence[int]) -> DataError:
    """Scan the file for the first unparsable or non-finite cell (slow path, errors only)."""
    with path.open(encoding="utf-8-sig", newline="") as f:
        lines = iter(f)
        next(lines)
        for lineno, line in enumerate(lines, start=2):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            fields = line.rstrip("\r\n").split(",")
            if len(fields) != len(header):
                return DataError(
                    f"{path}: line {lineno} has {len(fields)} fields, expected {len(header)} "
                    f"like the header {header}"
                )
            for c in cols:
                cell = fields[c].strip()
                try:
                    v = float(cell)
                except ValueError:
                    return DataError(
                        f"{path}: line {lineno}, column {header[c]!r}: {cell!r} is not a number"
                    )
                if not math.isfinite(v):
                    return DataError(
                        f"{path}: line {lineno}, column {header[c]!r}: {cell!r}; "
                        "expected a finite number"
                    )
    return DataError(f"{path}: cannot parse as a comma-separated numeric table")


def read_columns(path: str | Path, names: Sequence[tuple[str, str]]) -> list[FloatArray]:
    """Read the named columns of a CSV file with a header line, as float arrays.

    Parameters
    ----------
    path : str or Path
        The file: comma-separated, first line the column names, ``#`` lines ignored.
    names : sequence of (column name, option that sets it)
        The option is quoted in the error message when the column is missing.
    """
    p = Path(path)
    header = _header(p)
    cols = [_find(p, header, n, opt) for n, opt in names]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "no data": reported below
            data = np.loadtxt(
                p, delimiter=",", skiprows=1, usecols=cols, ndmin=2, dtype=float,
                comments="#", encoding="utf-8-sig",
            )
    except ValueError:
        raise _locate_bad(p, header, cols) from None
    if data.shape[0] == 0:
        raise DataError(f"{p}: no data rows after the header")
    if not np.isfinite(data).all():
        raise _locate_bad(p, header, cols)
    out = [np.ascontiguousarray(data[:, i]) for i in range(len(cols))]
    t = out[0]
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0)) + 1
        what = "duplicate" if d[i - 1] == 0 else "decreasing"
        raise DataError(
            f"{p}: column {header[cols[0]]!r}, data row {i + 1}: {what} time {t[i]!r} after "
            f"{t[i - 1]!r}; expected strictly increasing times"
        )
    return out


def _angles(values: FloatArray, units: Units) -> FloatArray:
    if units == "rad":
        return np.degrees(values)
    if units != "deg":
        raise DataError(f"units: expected 'deg' or 'rad', got {units!r}")
    return values


def load_single_csv(
    path: str | Path,
    *,
    time_col: str = "time",
    reference_col: str = "reference",
    device_col: str = "device",
    units: Units = "deg",
) -> Streams:
    """One CSV with columns time (s), reference and device (``units``), same instants."""
    names = [
        (time_col, "--time-col"),
        (reference_col, "--reference-col"),
        (device_col, "--device-col"),
    ]
    t, x, y = read_columns(path, names)
    return Streams(t, _angles(x, units), t, _angles(y, units), str(path))


def _angle_column(path: Path, time_col: str, name: str | None, option: str) -> str:
    if name is not None:
        return name
    others = [c for c in _header(path) if c != time_col]
    if len(others) != 1:
        raise DataError(
            f"{path}: expected one angle column beside {time_col!r}, found {others}; "
            f"choose one with {option}"
        )
    return others[0]


def load_csv_pair(
    reference: str | Path,
    device: str | Path,
    *,
    time_col: str = "time",
    reference_col: str | None = None,
    device_col: str | None = None,
    units: Units = "deg",
) -> Streams:
    """Two CSVs, each with ``time_col`` (s) and one angle column (``units``), any rates.

    The angle column is the one named, or else the only column beside the time.
    """
    rp, dp = Path(reference), Path(device)
    rc = _angle_column(rp, time_col, reference_col, "--reference-col")
    dc = _angle_column(dp, time_col, device_col, "--device-col")
    tr, xr = read_columns(rp, [(time_col, "--time-col"), (rc, "--reference-col")])
    td, yd = read_columns(dp, [(time_col, "--time-col"), (dc, "--device-col")])
    return Streams(tr, _angles(xr, units), td, _angles(yd, units), f"{rp} + {dp}")
