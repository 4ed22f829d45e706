"""The digest of a recording's data (``benchctl.recording.digest``): equal exactly when every
data file is, but for the two fields of events.jsonl that cannot be the same."""

from __future__ import annotations

import json
from pathlib import Path

from benchctl.recording.digest import DATA_FILES, combined_digest, data_digest, file_digest


def _recording(folder: Path, *, path: str, version: str, angle: str = "1.25",
               driver: str = "/a/drivers/x.eds") -> Path:
    folder.mkdir(parents=True)
    (folder / "stand.csv").write_text(f"t,roll_deg\n0.0,{angle}\n")
    (folder / "instrument.csv").write_text("t,roll_deg\n0.01,1.2\n")
    (folder / "setpoints.csv").write_text("t_slot,roll_deg\n0.0,1.0\n")
    events = [{"kind": "start", "recording": path, "software_version": version, "t": 0.0},
              {"kind": "identity", "eds": driver, "t": 0.5}]
    (folder / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    return folder


def test_two_recordings_of_one_run_in_other_folders_and_versions_digest_the_same(
        tmp_path: Path) -> None:
    a = _recording(tmp_path / "a", path="/runs/a", version="0.1")
    b = _recording(tmp_path / "b", path="/other/b", version="0.2.dev3")
    assert data_digest(a) == data_digest(b)
    assert combined_digest(a) == combined_digest(b)
    assert set(data_digest(a)) == set(DATA_FILES)


def test_one_sample_or_one_event_field_apart_digests_differ(tmp_path: Path) -> None:
    a = _recording(tmp_path / "a", path="/runs/a", version="0.1")
    b = _recording(tmp_path / "b", path="/runs/a", version="0.1", angle="1.26")
    assert file_digest(a / "stand.csv") != file_digest(b / "stand.csv")
    assert combined_digest(a) != combined_digest(b)
    c = _recording(tmp_path / "c", path="/runs/a", version="0.1", driver="/a/drivers/y.eds")
    assert file_digest(a / "events.jsonl") != file_digest(c / "events.jsonl")


def test_a_checkouts_folder_in_the_events_is_left_out_with_root(tmp_path: Path) -> None:
    a = _recording(tmp_path / "a", path="/runs/a", version="0.1", driver="/tree1/drivers/x.eds")
    b = _recording(tmp_path / "b", path="/runs/a", version="0.1", driver="/tree2/drivers/x.eds")
    assert combined_digest(a) != combined_digest(b)
    assert data_digest(a, "/tree1")["events.jsonl"] == data_digest(b, "/tree2")["events.jsonl"]


def test_a_file_not_recorded_is_none_and_counts(tmp_path: Path) -> None:
    a = _recording(tmp_path / "a", path="/runs/a", version="0.1")
    b = _recording(tmp_path / "b", path="/runs/a", version="0.1")
    (b / "setpoints.csv").unlink()
    assert data_digest(b)["setpoints.csv"] is None
    assert combined_digest(a) != combined_digest(b)
