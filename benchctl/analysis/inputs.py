"""CSV input for the analysis: one file ``time,reference,device`` or two files.

Strict: every problem is a ``DataError`` naming the file, the line (1-based, as an editor
shows it) or the column, the value, and what was expected. Times in seconds; angles in degrees
or radians (converted to degrees).
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.ranges import MAX_ABS_ANGLE_DEG, check_grid
from benchctl.errors import DataError
from benchctl.textfile import MAX_CSV_BYTES, InputFile, decode_utf8, input_file

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


def _header(path: Path, data: bytes) -> list[str]:
    end = data.find(b"\n")
    raw = data if end < 0 else data[: end + 1]
    try:
        first = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise DataError(
            f"{path}: line 1: byte 0x{raw[e.start]:02x} at offset {e.start} is not UTF-8; "
            "expected a UTF-8 text CSV file"
        ) from None
    if not first.strip():
        raise DataError(f"{path}: empty file; expected a header line with column names")
    if "\0" in first:
        raise DataError(f"{path}: line 1: a NUL character; expected a text CSV file")
    try:
        cells = next(csv.reader([first.rstrip("\r\n")]), [])
    except csv.Error as e:
        raise DataError(f"{path}: line 1: not a CSV header ({e})") from None
    return [c.strip().strip('"') for c in cells]


def _find(path: Path, header: list[str], name: str, option: str) -> int:
    if name not in header:
        raise DataError(
            f"{path}: no column {name!r}; the header has {header}; "
            f"name the column with {option}"
        )
    return header.index(name)


def _text_lines(path: Path, raw: bytes) -> list[str]:
    """The file's lines (universal newlines); ``DataError`` naming the line and byte offset
    of the first byte that is not UTF-8."""
    text = decode_utf8(raw, path, "CSV file", DataError)
    return io.StringIO(text, newline=None).read().split("\n")


def _data_lines(lines: list[str]) -> list[int]:
    """File line numbers (1-based) of the data rows: after the header, not blank, not
    ``#`` comments (as ``numpy.loadtxt`` reads them)."""
    return [
        n
        for n, line in enumerate(lines[1:], start=2)
        if line.split("#", 1)[0].strip()
    ]


def _locate_bad(path: Path, raw: bytes, header: list[str], cols: Sequence[int]) -> DataError:
    """Scan the file for the first unparsable or non-finite cell (slow path, errors only)."""
    try:
        lines = _text_lines(path, raw)
    except DataError as e:
        return e
    for lineno in _data_lines(lines):
        line = lines[lineno - 1]
        if "\0" in line:
            return DataError(f"{path}: line {lineno}: a NUL character; expected a text CSV file")
        fields = line.split("#", 1)[0].split(",")
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


def _check_first_row(path: Path, raw: bytes, header: list[str]) -> None:
    """The first data row has as many fields as the header (``numpy.loadtxt`` with
    ``usecols`` ignores extra ones, and refuses only rows unlike the first)."""
    with io.BytesIO(raw) as f:
        f.readline()
        for lineno, raw in enumerate(f, start=2):
            line = raw.decode("utf-8", errors="replace").split("#", 1)[0]
            if not line.strip():
                continue
            n = len(line.split(","))
            if n != len(header):
                raise DataError(
                    f"{path}: line {lineno} has {n} fields, expected {len(header)} like the "
                    f"header {header}"
                )
            return


def _row_label(path: Path, raw: bytes) -> Callable[[int], str]:
    """``where(i)`` for ``check_grid``: data row i+1 and its line in the file."""

    def where(i: int) -> str:
        try:
            line = _data_lines(_text_lines(path, raw))[i]
        except (DataError, IndexError):
            return f"data row {i + 1}"
        return f"data row {i + 1} (line {line})"

    return where


def _check_angles(p: Path, raw: bytes, header: list[str], col: int, v: FloatArray) -> None:
    bad = np.abs(v) > MAX_ABS_ANGLE_DEG
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(
            f"{p}: column {header[col]!r}, {_row_label(p, raw)(i)}: {float(v[i])!r}; "
            f"expected an angle, |value| ≤ {MAX_ABS_ANGLE_DEG:g}"
        )


def read_columns(path: str | Path, names: Sequence[tuple[str, str]]) -> list[FloatArray]:
    """Read the named columns of a CSV file with a header line, as float arrays.

    The first column named is the time: it must be strictly increasing and within the input
    ranges of ``benchctl.analysis.ranges.check_grid``; the others are angles,
    ``|value| ≤ MAX_ABS_ANGLE_DEG``. Any bytes at all give either the arrays or a
    ``DataError`` naming the file and the line.

    Parameters
    ----------
    path : str or Path
        The file: comma-separated, UTF-8, first line the column names, ``#`` lines ignored;
        a regular file of at most ``MAX_CSV_BYTES`` (``benchctl.textfile``), read once.
    names : sequence of (column name, option that sets it)
        The option is quoted in the error message when the column is missing.
    """
    p = Path(path)
    with _opened(p) as f:
        return _columns(p, f.data, names, f)


def _opened(path: Path) -> contextlib.AbstractContextManager[InputFile]:
    """The file, read: a regular file of at most ``MAX_CSV_BYTES``, else ``DataError``."""
    return input_file(path, "CSV file", DataError, MAX_CSV_BYTES)


def _loadtxt(raw: bytes, cols: list[int], opened: InputFile | None) -> FloatArray:
    """The columns ``cols`` of the CSV text ``raw``, as loadtxt parses them.

    loadtxt reads a file it opens itself in large blocks, but any file object it is handed
    line by line (twice the time: 0.2 against 0.45 s for 900 000 rows). So where the file is
    still open (``opened``) loadtxt reads it again by ``/proc/self/fd`` — the same inode, its
    bytes checked unchanged after —, else the bytes read, decoded chunk by chunk (a StringIO
    of the whole text held 4 bytes a character: 106 MiB more at the peak for a 27 MB CSV)."""
    kw = {"delimiter": ",", "skiprows": 1, "usecols": cols, "ndmin": 2, "dtype": float,
          "comments": "#", "encoding": "utf-8-sig"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "no data": reported by the caller
        if opened is not None and (again := opened.reopened()) is not None:
            data = np.loadtxt(again, **kw)  # type: ignore[call-overload]
            if opened.unchanged():
                return np.asarray(data, dtype=np.float64)
        text = io.TextIOWrapper(io.BytesIO(raw), encoding="utf-8-sig", newline=None)
        return np.asarray(np.loadtxt(text, **kw), dtype=np.float64)  # type: ignore[call-overload]


def _columns(p: Path, raw: bytes, names: Sequence[tuple[str, str]],
             opened: InputFile | None = None) -> list[FloatArray]:
    header = _header(p, raw)
    cols = [_find(p, header, n, opt) for n, opt in names]
    try:
        data = _loadtxt(raw, cols, opened)
    except (ValueError, TypeError, IndexError, OverflowError, csv.Error):
        raise _locate_bad(p, raw, header, cols) from None
    if data.shape[0] == 0:
        raise DataError(f"{p}: no data rows after the header")
    _check_first_row(p, raw, header)
    if not np.isfinite(data).all():
        raise _locate_bad(p, raw, header, cols)
    out = [np.ascontiguousarray(data[:, i]) for i in range(len(cols))]
    t = out[0]
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0)) + 1
        what = "duplicate" if d[i - 1] == 0 else "decreasing"
        raise DataError(
            f"{p}: column {header[cols[0]]!r}, data row {i + 1}: {what} time {float(t[i])!r} "
            f"after {float(t[i - 1])!r}; expected strictly increasing times"
        )
    if len(t) >= 2:
        check_grid(t, f"{p}: column {header[cols[0]]!r}", _row_label(p, raw))
    for c, v in zip(cols[1:], out[1:], strict=True):
        _check_angles(p, raw, header, c, v)
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


def _angle_column(path: Path, raw: bytes, time_col: str, name: str | None, option: str) -> str:
    if name is not None:
        return name
    others = [c for c in _header(path, raw) if c != time_col]
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
    with _opened(rp) as rf, _opened(dp) as df:
        rc = _angle_column(rp, rf.data, time_col, reference_col, "--reference-col")
        dc = _angle_column(dp, df.data, time_col, device_col, "--device-col")
        tr, xr = _columns(rp, rf.data, [(time_col, "--time-col"), (rc, "--reference-col")], rf)
        td, yd = _columns(dp, df.data, [(time_col, "--time-col"), (dc, "--device-col")], df)
    return Streams(tr, _angles(xr, units), td, _angles(yd, units), f"{rp} + {dp}")
