"""Read a recording back, whatever state the process that wrote it ended in."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from benchctl.errors import DataError
from benchctl.jsonout import dumps
from benchctl.recording.format import END_FILE, EVENTS_FILE, FORMAT_NAME, META_FILE, STREAM_FILES

if TYPE_CHECKING:
    from benchctl.analysis.timebase import Instants


def _read_stream(path: Path) -> tuple[list[str], NDArray[np.float64]]:
    """Columns and a float array; a torn (unterminated) last line is dropped."""
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
        from benchctl.analysis.timebase import Instants, instrument_timebase, stamp_error

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
            if by_clock is not None:  # every sample: a long round trip leaves its date exact
                t_ref, x_ref = by_clock, xr[okr]
            elif reference_timebase == "stand":
                raise DataError(f"{self.path}: the stand's samples carry no usable clock "
                                "(stand_time_s with its wrap, t_lo, t_hi)")

        def col(name: str) -> NDArray[np.float64] | None:
            c = inst.get(name)
            return None if c is None else c[okd]

        if td_ok.size < 2:
            return t_ref, x_ref, Instants(td_ok, "receipt"), yd[okd]
        if np.any(np.diff(td_ok) <= 0):  # decreasing receipts: left for the analysis to reject
            return t_ref, x_ref, Instants(td_ok, "receipt"), yd[okd]
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
        return t_ref, x_ref, tb.instants(), yd[okd]

    def _stand_clock(self, rows: NDArray[np.bool_]) -> Any:
        """The stand's samples (``rows``) dated by its own clock (``analysis.timebase.
        stand_clock``), or None when the recording has no such clock or it contradicts the
        exchanges' windows."""
        from benchctl.analysis.timebase import Instants, stand_clock

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
        t, err, info = stand_clock(ts, wrap, lo, hi)
        if not info["consistent"] or np.any(np.diff(t) <= 0):
            return None
        return Instants(t, "stand", err, info)

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
        from scipy.io import savemat

        from benchctl.redact import redact

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
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
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
        except json.JSONDecodeError:
            end = None
    streams: dict[str, dict[str, NDArray[np.float64]]] = {}
    for name, fname in STREAM_FILES.items():
        f = p / fname
        if not f.exists():
            continue
        header, data = _read_stream(f)
        streams[name] = {c: data[:, i].copy() for i, c in enumerate(header)}
    events: list[dict[str, Any]] = []
    ev = p / EVENTS_FILE
    if ev.is_file():
        for line in ev.read_text(encoding="utf-8").splitlines():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                break  # torn last line after a crash
    return Recording(path=p, meta=meta, end=end, streams=streams, events=events)
