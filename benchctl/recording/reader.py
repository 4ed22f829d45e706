"""Read a recording back, whatever state the process that wrote it ended in.

Reading checks the recording's integrity (``Recording.integrity``): each data file against the
rows and SHA-256 its ``end.json`` states (``benchctl.recording.writer``). ``verified`` when every
one matches, ``FAILED`` naming each file that does not (expected and found), ``unknown`` when
``end.json`` holds no such record (a recording of an older benchctl, or a run killed before it
closed): read as it is, but not verifiable. ``Recording.require_intact()`` raises
``IntegrityError`` on a failure; what reports a σ from a recording calls it.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.timebase import Instants, instrument_timebase, stamp_error, stand_clock
from benchctl.errors import DataError
from benchctl.jsonout import dumps
from benchctl.recording.format import (
    END_FILE,
    EVENTS_FILE,
    FORMAT_NAME,
    INTEGRITY_ALGORITHM,
    META_FILE,
    STREAM_FILES,
)
from benchctl.redact import redact


class IntegrityError(DataError):
    """A recording's data files are not as its run closed them (rows or SHA-256 differ from
    what ``end.json`` states): each file named with the expected and found values."""


VERIFIED, FAILED, UNKNOWN = "verified", "FAILED", "unknown"


@dataclass
class Integrity:
    """The integrity check of a recording: ``status`` verified | FAILED | unknown, the
    ``problems`` (one line per file that does not match), the files checked, and for unknown
    why (``note``)."""

    status: str
    problems: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    note: str = ""

    @property
    def ok(self) -> bool:
        return self.status == VERIFIED

    def text(self) -> str:
        """One line for the operator."""
        if self.status == VERIFIED:
            return (f"verified ({len(self.files)} files: rows and SHA-256 as end.json states: "
                    + ", ".join(self.files) + ")")
        if self.status == FAILED:
            return ("INTEGRITY FAILED: the data are not as the run closed them: "
                    + "; ".join(self.problems))
        return f"unknown, not verifiable ({self.note})"

    def to_dict(self) -> dict[str, Any]:
        return {"status": self.status, "problems": list(self.problems),
                "files": list(self.files), "note": self.note or None}


def _count_rows(raw: bytes, header_lines: int) -> int:
    return max(0, raw.count(b"\n") - header_lines)


def check_integrity(folder: Path, end: dict[str, Any] | None,
                    raw: dict[str, bytes | None]) -> Integrity:
    """Check the files ``end.json``'s ``integrity`` names against their bytes (``raw``: file
    name → bytes read, None when missing; a file not in ``raw`` is read here)."""
    if end is None:
        return Integrity(UNKNOWN, note="no end.json: the run did not close its recording")
    rec = end.get("integrity")
    files = rec.get("files") if isinstance(rec, dict) else None
    if not isinstance(rec, dict) or not isinstance(files, dict):
        return Integrity(UNKNOWN, note="end.json has no integrity record (written by a "
                                       "benchctl before it kept one)")
    if rec.get("algorithm") != INTEGRITY_ALGORITHM:
        return Integrity(UNKNOWN, note=f"end.json's integrity algorithm "
                                       f"{rec.get('algorithm')!r} is not {INTEGRITY_ALGORITHM!r}")
    problems: list[str] = []
    for name, want in files.items():
        path = folder / name
        if not isinstance(want, dict):
            problems.append(f"{path}: end.json's entry is not an object: {want!r}")
            continue
        data = raw[name] if name in raw else _read_or_none(path)
        if data is None:
            problems.append(f"{path}: missing (end.json states {want.get('rows', '?')} rows, "
                            f"SHA-256 {want.get('sha256')})")
            continue
        found_rows = _count_rows(data, 0 if name in (EVENTS_FILE, META_FILE) else 1)
        digest = hashlib.sha256(data).hexdigest()
        diff = []
        if "rows" in want and want["rows"] != found_rows:
            diff.append(f"{found_rows} rows found, end.json states {want['rows']}")
        if "bytes" in want and want["bytes"] != len(data):
            diff.append(f"{len(data)} bytes found, end.json states {want['bytes']}")
        if want.get("sha256") != digest:
            diff.append(f"SHA-256 {digest} found, end.json states {want.get('sha256')}")
        if diff:
            problems.append(f"{path}: " + ", ".join(diff))
    return Integrity(FAILED if problems else VERIFIED, problems, list(files))


def verify_recording(path: str | Path) -> Integrity:
    """The integrity of the recording in ``path`` alone (its streams not parsed): see
    ``check_integrity``; unknown when it is no recording or its end.json is unreadable."""
    p = Path(path)
    if not (p / META_FILE).is_file():
        return Integrity(UNKNOWN, note=f"{p}: no recording here (no {META_FILE})")
    end = None
    raw_end = _read_or_none(p / END_FILE)
    if raw_end is not None:
        try:
            end = json.loads(raw_end.decode("utf-8"))
        except (ValueError, UnicodeDecodeError):
            return Integrity(UNKNOWN, note=f"{p / END_FILE}: not valid JSON")
    return check_integrity(p, end if isinstance(end, dict) else None, {})


def _read_or_none(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except OSError:
        return None


def _read_stream(path: Path, raw: bytes | None = None) -> tuple[list[str], NDArray[np.float64]]:
    """Columns and a float array; a torn (unterminated) last line is dropped."""
    if raw is None:
        try:
            raw = path.read_bytes()
        except OSError as e:
            raise DataError(f"{path}: cannot read recording stream: {e.strerror}") from None
    if not raw:
        raise DataError(f"{path}: empty stream file (no header)")
    text = raw.decode("utf-8", errors="replace")
    if not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    lines = text.splitlines()
    header = lines[0].split(",")
    rows = lines[1:]
    if not rows:
        return header, np.empty((0, len(header)))
    try:
        data = np.loadtxt(rows, delimiter=",", ndmin=2, converters=None, dtype=float)
    except ValueError:
        # empty fields (None) → NaN, row by row
        data = np.array(
            [[float(v) if v else np.nan for v in r.split(",")] for r in rows], dtype=float
        )
    if data.shape[1] != len(header):
        raise DataError(f"{path}: rows have {data.shape[1]} fields, header has {len(header)}")
    return header, data


def resolve_batches(
    t_host: NDArray[np.float64], device_time_s: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Receipt times with batches told apart: strictly increasing where the reader stamped
    several samples with one receipt time (lines that arrived in one read).

    The last sample of a batch keeps the receipt time; the earlier ones are dated back by their
    own device-time differences when the instrument sends a time, else by the median interval
    of the stream (the instrument's own period), and spread evenly after the previous sample
    when that would not leave them after it. Times that are already increasing are
    returned unchanged (the same array). Receipt times of one reader never decrease; a
    decrease is left for the analysis to reject.

    Parameters
    ----------
    t_host : ndarray
        Receipt instants, monotonic seconds.
    device_time_s : ndarray, optional
        The instrument's own time stamps (s), NaN where absent.
    """
    t = np.asarray(t_host, dtype=float)
    if t.size < 2:
        return t
    d = np.diff(t)
    if not np.any(d == 0):
        return t
    pos = d[d > 0]
    step = float(np.median(pos)) if pos.size else 0.0
    out = t.copy()
    i = t.size - 1
    while i > 0:
        j = i
        while j > 0 and t[j - 1] == t[i]:
            j -= 1
        for m in range(i - 1, j - 1, -1):  # date back m = i-1 … j from the batch's last sample
            dd = math.nan
            if device_time_s is not None:
                dd = float(device_time_s[m + 1] - device_time_s[m])
            if not (math.isfinite(dd) and 0.0 < dd < 10.0 * step):
                dd = step
            out[m] = out[m + 1] - dd
        if j > 0 and out[j] <= t[j - 1]:  # the batch came soon after the previous sample
            lb, n = t[j - 1], i - j + 1
            out[j:i] = lb + (t[i] - lb) * np.arange(1, n) / n
        i = j - 1
    return out


WINDOW_MARGIN_S = 1.0  # reference kept beyond the analysis window, to evaluate it at the ends
RTT_OUTLIER_MIN_S = 0.005  # stand samples with a longer round trip than this …
RTT_OUTLIER_FACTOR = 5.0  # … and than this × the median are left out (their stamp is uncertain)


@dataclass
class Recording:
    """A loaded recording: metadata, end record (None if the writer never closed) and streams."""

    path: Path
    meta: dict[str, Any]
    end: dict[str, Any] | None
    streams: dict[str, dict[str, NDArray[np.float64]]]
    events: list[dict[str, Any]]
    integrity: Integrity = field(default_factory=lambda: Integrity(UNKNOWN, note="not checked"))

    def require_intact(self) -> None:
        """Raise ``IntegrityError`` when the data files are not as the run closed them (an
        integrity ``unknown`` passes: nothing to check against)."""
        if self.integrity.status == FAILED:
            raise IntegrityError(
                f"{self.path}: INTEGRITY FAILED, the recording was altered after its run closed "
                "it: " + "; ".join(self.integrity.problems)
            )

    @property
    def axes(self) -> tuple[str, ...]:
        return tuple(self.meta.get("axes", ("roll",)))

    @property
    def state(self) -> str:
        """done, aborted, or incomplete (no end record: the process died)."""
        return str(self.end["state"]) if self.end else "incomplete"

    def column(self, stream: str, name: str) -> NDArray[np.float64]:
        try:
            return self.streams[stream][name]
        except KeyError:
            raise DataError(f"{self.path}: stream {stream!r} has no column {name!r}") from None

    def pair(
        self, axis: str, window: bool = True, timebase: str = "best",
        reference_timebase: str = "best",
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(t_reference, reference_deg, t_device, device_deg) for one axis, NaN rows removed.

        The instants are on the host's monotonic clock, from the best time base each stream
        has (see ``timebases``): the instrument's from its own clock or counter, else the CAN
        adapter's timestamps, else a clock fitted to its receipt stamps (``timebase`` picks one:
        ``best``, ``device``, ``adapter``, ``fitted`` or ``receipt``); the stand's by its own
        clock where its map has one (``stand``, see ``_stand_clock``), else at each reply's
        stamp (``stamp``; ``_stamp_certain``: replies that took far longer than usual left
        out) — ``reference_timebase`` picks one: ``best``, ``stand`` or ``stamp``.
        Both are ``benchctl.analysis.timebase.Instants``: labelled with their time base and
        residual error, which ``analyze`` reports (``timing``), also after cropping.

        A finished run's recording (``end.json`` with ``analysis_window`` [t0, t1]) gives the
        instrument's samples inside that window and the reference up to ``WINDOW_MARGIN_S``
        beyond it, so ``benchctl analyze`` on it reproduces the verdict's σ; pass
        ``window=False`` for everything recorded (prechecks, fades, settling).
        """
        if axis not in self.axes:
            raise DataError(f"{self.path}: no axis {axis!r}; recorded axes are {list(self.axes)}")
        tr, xr, td, yd = self.timebases(axis, timebase, reference_timebase)
        win = self.analysis_window if window else None
        if win is not None:
            lo, hi = win
            kr = (tr >= lo - WINDOW_MARGIN_S) & (tr <= hi + WINDOW_MARGIN_S)
            kd = (td >= lo) & (td <= hi)
            return tr[kr], xr[kr], td[kd], yd[kd]
        return tr, xr, td, yd

    def timebases(
        self, axis: str, timebase: str = "best", reference_timebase: str = "best"
    ) -> tuple[Instants, NDArray[np.float64], Instants, NDArray[np.float64]]:
        """Both streams of one axis on their time bases, whole (see ``pair``)."""
        tr, xr = self.column("stand", "t_host"), self.column("stand", f"{axis}_deg")
        td, yd = self.column("instrument", "t_host"), self.column("instrument", f"{axis}_deg")
        okr = np.isfinite(tr) & np.isfinite(xr)
        okd = np.isfinite(td) & np.isfinite(yd)
        inst = self.streams["instrument"]
        dev_t = inst.get("device_time_s")
        td_ok = resolve_batches(td[okd], None if dev_t is None else dev_t[okd])
        stamp = "request_end" if self._driver("stand") == "modbus-rtu" else "midpoint"
        keep = self._stamp_certain()[okr]
        err = stamp_error(self.column("stand", "rtt_s")[okr][keep], stamp)
        t_ref = Instants(tr[okr][keep], stamp, err, {"dropped": int((~keep).sum())})
        x_ref = xr[okr][keep]
        if reference_timebase in ("best", "stand"):
            by_clock = self._stand_clock(okr)
            if by_clock is not None:  # a long round trip leaves its date exact, unless the
                # stall in it was long enough to hide the stand clock's wrap (left out)
                t_ref, x_ref = by_clock[0], xr[okr][by_clock[1]]
            elif reference_timebase == "stand":
                raise DataError(f"{self.path}: the stand's samples carry no usable clock "
                                "(stand_time_s with its wrap, t_lo, t_hi)")
        t_ref = Instants(t_ref, t_ref.timebase, t_ref.residual_s,
                         {**t_ref.info, **self.encoder})

        def col(name: str) -> NDArray[np.float64] | None:
            c = inst.get(name)
            return None if c is None else c[okd]

        if td_ok.size < 2 or np.any(np.diff(td_ok) <= 0):
            # too few, or decreasing receipts: left for the analysis to reject
            return t_ref, x_ref, self._timing_applied(Instants(td_ok, "receipt")), yd[okd]
        try:
            tb = instrument_timebase(
                td_ok,
                device_time=col("device_time_s"),
                counter=col("counter"),
                adapter_time=col("adapter_time_s"),
                driver=self._driver("instrument"),
                prefer=timebase,
            )
        except ValueError as e:
            raise DataError(f"{self.path}: instrument: {e}") from None
        return t_ref, x_ref, self._timing_applied(tb.instants()), yd[okd]

    def _config_number(self, section: str, key: str, *, nonneg: bool) -> float | None:
        """``<section>.<key>`` of the bench config the recording keeps (meta.json), when it is a
        finite number (≥ 0 with ``nonneg``); None when absent or anything else."""
        cfg = self.meta.get("config")
        sec = cfg.get(section) if isinstance(cfg, dict) else None
        v = sec.get(key) if isinstance(sec, dict) else None
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) \
                and (v >= 0 or not nonneg):
            return float(v)
        return None

    @property
    def timing_offset_s(self) -> float:
        """The bench's stream-to-stream offset its config's timing calibration states
        (``timing.offset_s``, s; 0 when none): how late the bench stamps the instrument's
        samples relative to the stand's."""
        return self._config_number("timing", "offset_s", nonneg=False) or 0.0

    @property
    def timing_offset_u_s(self) -> float:
        """The standard uncertainty the timing calibration states for ``timing_offset_s``
        (``timing.uncertainty_s``, s; 0 when none)."""
        return self._config_number("timing", "uncertainty_s", nonneg=True) or 0.0

    @property
    def encoder(self) -> dict[str, float | None]:
        """The reference angle's resolution and standard uncertainty its bench config states
        (``stand.encoder_resolution_deg``, ``stand.encoder_uncertainty_deg``, deg; None: not
        stated, or not a finite number ≥ 0), as the reference's instants carry them into σ's
        uncertainty budget (``info``, ``benchctl.analysis.budget.Reference.of``)."""
        return {key: self._config_number("stand", key, nonneg=True)
                for key in ("encoder_resolution_deg", "encoder_uncertainty_deg")}

    def _timing_applied(self, t: Instants) -> Instants:
        """The instrument's instants moved earlier by the bench's calibrated offset
        (``timing_offset_s``), labelled with it and its uncertainty (``info["timing_offset_s"]``,
        ``info["timing_offset_u_s"]``)."""
        off = self.timing_offset_s
        if off == 0.0:
            return t
        return Instants(np.asarray(t) - off, t.timebase, t.residual_s,
                        {**t.info, "timing_offset_s": off,
                         "timing_offset_u_s": self.timing_offset_u_s})

    def _stand_clock(self, rows: NDArray[np.bool_]) -> Any:
        """The stand's samples (``rows``) dated by its own clock (``analysis.timebase.
        stand_clock``) and which of them it could date, or None when the recording has no such
        clock or it contradicts the exchanges' windows."""
        st = self.streams["stand"]
        ts, lo, hi = st.get("stand_time_s"), st.get("t_lo"), st.get("t_hi")
        extra = ((self.meta.get("devices") or {}).get("stand") or {}).get("extra") or {}
        try:
            wrap = float(extra.get("sample_time_wrap_s", "nan"))
        except (TypeError, ValueError):
            return None
        if ts is None or lo is None or hi is None or not math.isfinite(wrap) or wrap <= 0:
            return None
        ts, lo, hi = ts[rows], lo[rows], hi[rows]
        if ts.size < 3 or not (np.isfinite(ts).all() and np.isfinite(lo).all()
                               and np.isfinite(hi).all()):
            return None
        # RTU: the stand answers with the state it has as the request is complete, the start
        # of the window (the reply's wire time ends it); TCP: anywhere in the round trip
        anchor = "earliest" if self._driver("stand") == "modbus-rtu" else "window"
        t, err, info = stand_clock(ts, wrap, lo, hi, anchor=anchor)
        dated = np.isfinite(t)
        t = t[dated]
        if not info["consistent"] or t.size < 3 or np.any(np.diff(t) <= 0):
            return None
        return Instants(t, "stand", err, info), dated

    def _stamp_certain(self) -> NDArray[np.bool_]:
        """Stand samples whose stamp is certain: a sample is stamped at the midpoint of its
        request and reply (Modbus TCP) or at the end of its request on the wire (RTU), so its
        time is uncertain by up to its round trip; one whose round trip took longer than
        ``max(RTT_OUTLIER_MIN_S, RTT_OUTLIER_FACTOR × median)`` (the host or the stand was held
        up mid-request) is left out — a gap the reference spline bridges or the analysis masks,
        never a sample at the wrong time."""
        rtt = self.column("stand", "rtt_s")
        ok = np.isfinite(rtt)
        if not np.any(ok):
            return np.ones(rtt.shape, dtype=bool)
        bound = max(RTT_OUTLIER_MIN_S, RTT_OUTLIER_FACTOR * float(np.median(rtt[ok])))
        return ~ok | (rtt <= bound)

    def _driver(self, device: str) -> str | None:
        cfg = self.meta.get("config")
        sec = cfg.get(device) if isinstance(cfg, dict) else None
        drv = sec.get("driver") if isinstance(sec, dict) else None
        return drv if isinstance(drv, str) else None

    @property
    def analysis_window(self) -> tuple[float, float] | None:
        """[t0, t1] (monotonic s) the run's verdict was computed on, if it finished."""
        w = (self.end or {}).get("analysis_window")
        if not (isinstance(w, list) and len(w) == 2):
            return None
        return float(w[0]), float(w[1])

    def export_csv(self, folder: str | Path) -> list[Path]:
        """One CSV per stream into ``folder``; returns the files written."""
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for name, cols in self.streams.items():
            dest = out / f"{name}.csv"
            names = list(cols)
            arr = np.column_stack([cols[c] for c in names]) if names else np.empty((0, 0))
            np.savetxt(dest, arr, delimiter=",", header=",".join(names), comments="", fmt="%.17g")
            written.append(dest)
        return written

    def export_mat(self, dest: str | Path) -> Path:
        """All streams and metadata into one MATLAB .mat file (struct per stream)."""
        from scipy.io import savemat  # scipy.io: about 0.2 s to import, for a .mat export only

        d = Path(dest)
        payload: dict[str, Any] = {name: dict(cols) for name, cols in self.streams.items()}
        payload["meta_json"] = dumps(redact(self.meta))  # an older recording's password too
        payload["end_json"] = dumps(self.end)
        savemat(d, payload, do_compression=True)
        return d


def load_recording(path: str | Path) -> Recording:
    """Load a recording folder. Raises ``DataError`` naming the file when it is unusable."""
    p = Path(path)
    meta_path = p / META_FILE
    try:
        meta_raw = meta_path.read_bytes()
        meta = json.loads(meta_raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise DataError(f"{meta_path}: corrupt metadata: {e}") from None
    except OSError as e:
        raise DataError(f"{meta_path}: not a benchctl recording ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise DataError(f"{meta_path}: corrupt metadata: {e}") from None
    if meta.get("format") != FORMAT_NAME:
        raise DataError(f"{meta_path}: format is {meta.get('format')!r}, expected {FORMAT_NAME!r}")
    end = None
    end_path = p / END_FILE
    if end_path.is_file():
        try:
            end = json.loads(end_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError):
            end = None
        if not isinstance(end, dict):
            end = None
    raw: dict[str, bytes | None] = {META_FILE: meta_raw}
    streams: dict[str, dict[str, NDArray[np.float64]]] = {}
    for name, fname in STREAM_FILES.items():
        f = p / fname
        if not f.exists():
            raw[fname] = None
            continue
        try:
            raw[fname] = f.read_bytes()
        except OSError as e:
            raise DataError(f"{f}: cannot read recording stream: {e.strerror}") from None
        header, data = _read_stream(f, raw[fname])
        streams[name] = {c: data[:, i].copy() for i, c in enumerate(header)}
    events: list[dict[str, Any]] = []
    ev = p / EVENTS_FILE
    raw[EVENTS_FILE] = _read_or_none(ev) if ev.is_file() else None
    ev_raw = raw[EVENTS_FILE]
    if ev_raw is not None:
        for line in ev_raw.decode("utf-8", errors="replace").splitlines():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                break  # torn last line after a crash
    integrity = check_integrity(p, end, raw)
    return Recording(path=p, meta=meta, end=end, streams=streams, events=events,
                     integrity=integrity)
