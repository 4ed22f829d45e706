"""CSV inputs: strict validation with messages naming the file, line, column and value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchctl.analysis.inputs import load_csv_pair, load_single_csv
from benchctl.errors import DataError


def write(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text(header + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def good_rows(n: int = 5) -> list[str]:
    return [f"{i * 0.1:.1f},{i * 1.0},{i * 1.0 + 0.5}" for i in range(n)]


def test_single_csv_and_radians(tmp_path: Path) -> None:
    f = write(tmp_path / "a.csv", "time,reference,device", good_rows())
    s = load_single_csv(f)
    assert np.allclose(s.t_ref, [0, 0.1, 0.2, 0.3, 0.4]) and s.t_dev is s.t_ref
    assert np.allclose(s.y_dev - s.x_ref, 0.5)
    r = load_single_csv(f, units="rad")
    assert r.x_ref[1] == pytest.approx(np.degrees(1.0))


def test_named_columns_in_any_order(tmp_path: Path) -> None:
    rows = [f"{i},{i * 0.01},{i * 2}" for i in range(4)]
    f = write(tmp_path / "b.csv", "stand, t ,imu", rows)
    s = load_single_csv(f, time_col="t", reference_col="stand", device_col="imu")
    assert np.allclose(s.t_ref, [0, 0.01, 0.02, 0.03]) and np.allclose(s.x_ref, [0, 1, 2, 3])


def test_two_files_at_different_rates(tmp_path: Path) -> None:
    ref = write(tmp_path / "ref.csv", "time,stand_deg", [f"{i * 0.01},{i}" for i in range(10)])
    dev = write(tmp_path / "dev.csv", "time,roll", [f"{i * 0.03},{i}" for i in range(3)])
    s = load_csv_pair(ref, dev)
    assert len(s.t_ref) == 10 and len(s.t_dev) == 3 and "ref.csv" in s.source


def test_two_files_ambiguous_angle_column(tmp_path: Path) -> None:
    ref = write(tmp_path / "ref.csv", "time,a,b", ["0,1,2", "1,2,3"])
    dev = write(tmp_path / "dev.csv", "time,roll", ["0,1", "1,2"])
    with pytest.raises(DataError, match=r"ref\.csv.*--reference-col"):
        load_csv_pair(ref, dev)
    s = load_csv_pair(ref, dev, reference_col="b")
    assert np.allclose(s.x_ref, [2, 3])


H = "time,reference,device"


@pytest.mark.parametrize(
    ("header", "rows", "match"),
    [
        ("time,reference", good_rows(), r"no column 'device'.*--device-col"),
        (H, ["0,1,2", "0.1,1,abc"], r"line 3, column 'device': 'abc' is not a number"),
        (H, ["0,1,2", "0.1,nan,2"], r"line 3, column 'reference': 'nan'; expected a finite"),
        (H, ["0,1,2", "0.1,1,inf"], r"line 3, column 'device': 'inf'"),
        (H, ["0,1,2", "0.1,1"], r"line 3 has 2 fields, expected 3"),
        (H, ["0,1,2", "0.2,1,2", "0.1,1,2"], r"column 'time', data row 3: decreasing"),
        (H, ["0,1,2", "0,1,2"], r"data row 2: duplicate time"),
        (H, [], r"no data rows"),
    ],
)
def test_bad_csv(tmp_path: Path, header: str, rows: list[str], match: str) -> None:
    f = write(tmp_path / "bad.csv", header, rows)
    with pytest.raises(DataError, match=match) as e:
        load_single_csv(f)
    assert "bad.csv" in str(e.value)


def test_empty_and_missing_files(tmp_path: Path) -> None:
    (tmp_path / "empty.csv").write_text("", encoding="utf-8")
    with pytest.raises(DataError, match="empty file"):
        load_single_csv(tmp_path / "empty.csv")
    with pytest.raises(DataError, match="cannot read"):
        load_single_csv(tmp_path / "nope.csv")


def test_bad_units(tmp_path: Path) -> None:
    f = write(tmp_path / "a.csv", "time,reference,device", good_rows())
    with pytest.raises(DataError, match="units"):
        load_single_csv(f, units="grad")  # type: ignore[arg-type]
