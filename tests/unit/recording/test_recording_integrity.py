"""A recording knows when it was altered: end.json holds each data file's rows and SHA-256, and
reading the recording checks them.

- an untouched recording verifies; ``analyze`` gives its σ (exit 0);
- stand.csv truncated after the run: ``analyze`` exits 2 naming the file with the rows found and
  stated, ``recording show`` states INTEGRITY FAILED, the Python API raises;
- one byte changed, rows unchanged: the hash mismatch is reported (expected and found);
- a recording without the record (an older benchctl, or a killed run: no end.json) reads as
  before and says its integrity is unknown;
- property: random rows and events written through the writer — end.json's rows and SHA-256
  match the files' bytes hashed and counted independently.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchctl.cli import main
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.errors import RecordingError
from benchctl.evaluate import analyze_recording
from benchctl.recording import IntegrityError, RecordingWriter, load_recording, verify_recording

STATUS = StandStatus(ready=True, enabled=True, moving=True, fault=False, estop=False,
                     limit=False)
DATA_FILES = ("stand.csv", "instrument.csv", "setpoints.csv", "events.jsonl")


def make_recording(folder: Path, seconds: float = 40.0) -> Path:
    """A closed recording of one axis: stand 100 Hz, instrument 50 Hz (gain 0.99, noise)."""
    rng = np.random.default_rng(11)
    w = RecordingWriter(folder, ("roll",), {"serial": "INT-1"})

    def motion(t: np.ndarray) -> np.ndarray:
        return 2.0 * np.sin(2 * np.pi * 0.2 * t) + 1.0 * np.sin(2 * np.pi * 0.45 * t + 1.0)

    ts = 100.0 + np.arange(int(seconds * 100)) / 100.0
    for t, x in zip(ts.tolist(), motion(ts).tolist(), strict=True):
        w.write_stand(StandSample(t_host=t, rtt_s=0.002, angle_deg={"roll": x},
                                  rate_deg_s={"roll": 0.0}, setpoint_deg={"roll": x},
                                  status=STATUS))
        w.write_setpoint(t, {"roll": x}, t)
    ti = 100.5 + np.arange(int((seconds - 1) * 50)) / 50.0
    yi = 0.99 * motion(ti) + rng.normal(0.0, 0.02, ti.size)
    for i, (t, y) in enumerate(zip(ti.tolist(), yi.tolist(), strict=True)):
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": y}, counter=i))
    w.event("note", text="made by the test")
    w.close("done", "PASS")
    return folder


def _analyze(rec: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["analyze", str(rec), "--axis", "roll", "--json"])
    out, err = capsys.readouterr()
    return code, out, err


def _show(rec: Path, capsys: pytest.CaptureFixture[str]) -> str:
    assert main(["recording", "show", str(rec)]) == 0
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_recording(tmp_path_factory.mktemp("integrity") / "rec")


def _copy(src: Path, dest: Path) -> Path:
    dest.mkdir()
    for f in src.iterdir():
        (dest / f.name).write_bytes(f.read_bytes())
    return dest


def test_an_untouched_recording_verifies(pristine: Path, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    rec = _copy(pristine, tmp_path / "rec")
    end = json.loads((rec / "end.json").read_text())
    files = end["integrity"]["files"]
    assert end["integrity"]["algorithm"] == "sha256"
    assert set(files) == {*DATA_FILES, "meta.json"}
    assert files["stand.csv"]["rows"] == 4000 and files["instrument.csv"]["rows"] == 1950
    assert files["events.jsonl"]["rows"] == 1
    assert not (rec / "end.json.reserve").exists()
    r = load_recording(rec)
    assert r.integrity.status == "verified" and r.integrity.ok
    r.require_intact()
    code, out, _ = _analyze(rec, capsys)
    assert code == 0
    doc = json.loads(out)
    assert doc["recording"]["integrity"]["status"] == "verified"
    assert 0.0 < doc["sigma"] < 0.2
    assert "integrity  verified" in _show(rec, capsys)


def test_truncated_stand_csv_is_refused_naming_the_file(
    pristine: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = _copy(pristine, tmp_path / "rec")
    stand = rec / "stand.csv"
    lines = stand.read_bytes().splitlines(keepends=True)
    stand.write_bytes(b"".join(lines[:2001]))  # header + 2000 of 4000 rows: whole lines
    assert load_recording(rec).streams["stand"]["t_host"].size == 2000  # readable as ever …
    code, out, err = _analyze(rec, capsys)
    assert code == 2 and out == ""  # … but no σ from it
    assert f"{stand}: 2000 rows found, end.json states 4000" in err, err
    assert "INTEGRITY FAILED" in err and "SHA-256" in err
    shown = _show(rec, capsys)
    assert "state      done (PASS) — INTEGRITY FAILED" in shown, shown
    assert f"{stand}: 2000 rows found, end.json states 4000" in shown
    with pytest.raises(IntegrityError, match=r"stand\.csv: 2000 rows found, end\.json states 4000"):
        analyze_recording(rec, "roll")
    assert verify_recording(rec).status == "FAILED"


def test_one_byte_changed_is_a_hash_mismatch(
    pristine: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = _copy(pristine, tmp_path / "rec")
    inst = rec / "instrument.csv"
    raw = bytearray(inst.read_bytes())
    i = raw.index(b"\n", raw.index(b"\n") + 1) - 3  # a digit of the first row's last value
    assert chr(raw[i]).isdigit()
    raw[i] = ord("7") if raw[i] != ord("7") else ord("3")
    inst.write_bytes(bytes(raw))
    want = json.loads((rec / "end.json").read_text())["integrity"]["files"]["instrument.csv"]
    found = hashlib.sha256(bytes(raw)).hexdigest()
    code, _, err = _analyze(rec, capsys)
    assert code == 2
    assert f"{inst}: SHA-256 {found} found, end.json states {want['sha256']}" in err, err
    assert "rows found" not in err  # the same rows: only the hash tells
    assert "INTEGRITY FAILED" in _show(rec, capsys)


def test_a_recording_without_the_record_is_read_as_unknown(
    pristine: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    old = _copy(pristine, tmp_path / "old")  # an older benchctl: no integrity in end.json
    end = json.loads((old / "end.json").read_text())
    del end["integrity"]
    (old / "end.json").write_text(json.dumps(end))
    r = load_recording(old)
    assert r.state == "done" and r.integrity.status == "unknown"
    code, out, _ = _analyze(old, capsys)
    assert code == 0
    status = json.loads(out)["recording"]
    assert status["integrity"]["status"] == "unknown"
    assert "integrity unknown, not verifiable" in status["note"]
    assert "unknown, not verifiable: end.json has no integrity record" in _show(old, capsys)
    killed = _copy(pristine, tmp_path / "killed")  # a killed run: no end.json at all
    (killed / "end.json").unlink()
    r = load_recording(killed)
    assert r.state == "incomplete" and r.integrity.status == "unknown"
    assert "unknown, not verifiable: no end.json" in _show(killed, capsys)


def test_a_stream_whose_write_failed_is_vouched_for_as_found(tmp_path: Path) -> None:
    """After a write error (disk full) the failed file is counted and hashed from the disk."""
    w = RecordingWriter(tmp_path / "rec", ("roll",), {})
    real = w._files["instrument"]

    class Full:
        def write(self, text: str) -> int:
            real.write(text[: len(text) // 2])  # half a line reached the disk
            real.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

    for k in range(3):
        w.write_instrument(InstrumentSample(float(k), {"roll": 0.5}, counter=k))
    w._files["instrument"] = Full()  # type: ignore[assignment]
    with pytest.raises(RecordingError):
        w.write_instrument(InstrumentSample(3.0, {"roll": 0.5}, counter=3))
    w.close("aborted", "recording: disk full")
    end = json.loads((tmp_path / "rec" / "end.json").read_text())
    entry = end["integrity"]["files"]["instrument.csv"]
    assert entry["rows"] == 3 and entry["after_write_error"] is True  # the torn row is no row
    assert load_recording(tmp_path / "rec").integrity.status == "verified"


# ------------------------------------------------------------------------------ property
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
value = st.one_of(finite, st.just(math.nan), st.just(math.inf), st.none())
stand_row = st.tuples(finite, value, value, value, st.integers(0, 65535))
inst_row = st.tuples(finite, value, st.one_of(st.none(), st.integers(0, 2**40)), value)
set_row = st.tuples(finite, value, value)
event = st.dictionaries(st.text(max_size=12), st.one_of(st.text(max_size=40), finite,
                                                        st.integers()), max_size=4)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(stands=st.lists(stand_row, max_size=40), insts=st.lists(inst_row, max_size=40),
       sets=st.lists(set_row, max_size=40), events=st.lists(event, max_size=10))
def test_written_rows_are_counted_and_hashed(
    tmp_path_factory: pytest.TempPathFactory, stands: list[Any], insts: list[Any],
    sets: list[Any], events: list[dict[str, Any]],
) -> None:
    folder = tmp_path_factory.mktemp("prop") / "rec"
    w = RecordingWriter(folder, ("roll",), {"serial": "P"})
    for t, a, r, sp, code in stands:
        w.write_stand(StandSample(t_host=t, rtt_s=0.001, angle_deg={"roll": a},
                                  rate_deg_s={"roll": r}, setpoint_deg={"roll": sp},
                                  status=dataclasses.replace(STATUS, fault_code=code)))
    for t, dev, counter, y in insts:
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": y},
                                            device_time_s=dev, counter=counter))
    for t, slot, x in sets:
        w.write_setpoint(t, {"roll": x}, slot)
    for e in events:
        w.event("note", payload=e)
    w.close("done", "")
    files = json.loads((folder / "end.json").read_text())["integrity"]["files"]
    want_rows = {"stand.csv": len(stands), "instrument.csv": len(insts),
                 "setpoints.csv": len(sets), "events.jsonl": len(events)}
    for name, rows in want_rows.items():
        data = (folder / name).read_bytes()
        header = 0 if name == "events.jsonl" else 1
        assert data.count(b"\n") - header == rows == files[name]["rows"], name
        assert files[name]["sha256"] == hashlib.sha256(data).hexdigest(), name
        assert files[name]["bytes"] == len(data), name
    meta = (folder / "meta.json").read_bytes()
    assert files["meta.json"]["sha256"] == hashlib.sha256(meta).hexdigest()
    assert load_recording(folder).integrity.status == "verified"


def test_show_states_an_integrity_failure(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """``benchctl show RUN`` checks the run's recording folder when it is here."""
    from archive_helpers import make_record
    from archive_helpers import make_recording as archived_recording

    runs = tmp_path / "runs"
    name = "20261120T080000Z_SN-1"
    rec = archived_recording(runs, name, record=make_record(name))
    assert main(["archive", "rebuild", str(runs), "--out", str(runs)]) == 0
    capsys.readouterr()
    assert main(["show", name, "--out", str(runs)]) == 0
    assert "integrity  verified" in capsys.readouterr().out
    inst = rec / "instrument.csv"
    inst.write_bytes(inst.read_bytes().replace(b"0.1", b"0.2", 1))
    assert main(["show", name, "--out", str(runs), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["integrity"]["status"] == "FAILED"
    assert f"{inst}: SHA-256" in doc["integrity"]["problems"][0]
    assert main(["show", name, "--out", str(runs)]) == 0
    assert "INTEGRITY FAILED" in capsys.readouterr().out


def test_room_given_back_on_a_full_disk_is_not_taken_by_rows(tmp_path: Path) -> None:
    """release_reserve (the abort on a full disk): the reserve is gone, stream rows are dropped
    and counted, events still go in, and the files still verify."""
    w = RecordingWriter(tmp_path / "rec", ("roll",), {})
    assert (tmp_path / "rec" / "end.json.reserve").stat().st_size == w.reserve_bytes > 0
    w.write_instrument(InstrumentSample(0.0, {"roll": 0.5}, counter=0))
    w.release_reserve()
    assert not (tmp_path / "rec" / "end.json.reserve").exists()
    for k in range(1, 4):
        w.write_instrument(InstrumentSample(float(k), {"roll": 0.5}, counter=k))
    w.event("shutdown", state="aborted")
    w.close("aborted", "recording: disk full")
    end = json.loads((tmp_path / "rec" / "end.json").read_text())
    assert end["dropped_rows"] == 3 and end["counts"]["instrument"] == 1
    assert end["integrity"]["files"]["events.jsonl"]["rows"] == 1
    assert load_recording(tmp_path / "rec").integrity.status == "verified"


@settings(max_examples=50, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.sampled_from([*DATA_FILES, "meta.json"]), where=st.floats(0.0, 1.0),
       delta=st.integers(1, 255), cut=st.booleans())
def test_any_change_to_a_covered_file_is_found(
    tmp_path_factory: pytest.TempPathFactory, which: str, where: float, delta: int, cut: bool,
) -> None:
    """One byte changed, or the file cut anywhere: the check fails naming that file only."""
    folder = tmp_path_factory.mktemp("alter") / "rec"
    w = RecordingWriter(folder, ("roll",), {"serial": "A"})
    for k in range(20):
        w.write_instrument(InstrumentSample(float(k), {"roll": 0.25 * k}, counter=k))
        w.write_setpoint(float(k), {"roll": 0.25 * k}, float(k))
        w.write_stand(StandSample(t_host=float(k), rtt_s=0.001, angle_deg={"roll": 0.1 * k},
                                  rate_deg_s={"roll": 0.0}, setpoint_deg={"roll": 0.0},
                                  status=STATUS))
    w.event("note", text="x")
    w.close("done", "PASS")
    f = folder / which
    raw = bytearray(f.read_bytes())
    i = min(int(where * len(raw)), len(raw) - 1)
    if cut:
        raw = raw[:i]
    else:
        raw[i] = (raw[i] + delta) % 256
    f.write_bytes(bytes(raw))
    found = verify_recording(folder)
    assert found.status == "FAILED"
    assert len(found.problems) == 1 and found.problems[0].startswith(f"{f}: ")


def test_rows_are_written_while_meta_json_waits_for_the_disk(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """meta.json's rewrite ends in an fsync, which a busy disk can hold for seconds: the stand
    loop's and the reader's rows (and events) are written meanwhile, not held behind it; the
    rewrite then lands and the recording verifies."""
    import threading

    from benchctl.recording import writer as writer_mod

    w = RecordingWriter(tmp_path / "rec", ("roll",), {"serial": "M-1"})
    real = writer_mod.atomic_write_bytes
    entered, release = threading.Event(), threading.Event()

    def slow_disk(path: Path, data: bytes, **kw: Any) -> None:
        if path.name == "meta.json":
            entered.set()
            assert release.wait(60), "the test never released the disk"
        real(path, data, **kw)

    monkeypatch.setattr(writer_mod, "atomic_write_bytes", slow_disk)
    meta = threading.Thread(target=w.update_meta, kwargs={"mounting_check": {"ok": True}})
    meta.start()
    assert entered.wait(60)

    def rows() -> None:
        for k in range(200):
            w.write_stand(StandSample(t_host=float(k), rtt_s=0.002, angle_deg={"roll": 0.1},
                                      rate_deg_s={"roll": 0.0}, setpoint_deg={"roll": 0.1},
                                      status=STATUS))
            w.write_instrument(InstrumentSample(float(k), {"roll": 0.1}, counter=k))
        w.event("underrun", played=1, queued=1)

    writer = threading.Thread(target=rows)
    writer.start()
    writer.join(60)
    held = meta.is_alive()  # the meta.json write still waits for the disk…
    release.set()
    meta.join(60)
    assert held and not writer.is_alive()  # … and every row went in meanwhile
    assert w.counts["stand"] == w.counts["instrument"] == 200
    w.close("done", "PASS")
    assert json.loads((tmp_path / "rec" / "meta.json").read_text())["mounting_check"] == {
        "ok": True}
    assert load_recording(tmp_path / "rec").integrity.status == "verified"
