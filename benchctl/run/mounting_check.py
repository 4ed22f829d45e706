"""The mounting check's verdict from the tilt's samples: the stand's measured angles
interpolated at the instrument's instants, the response fitted and judged
(``benchctl.run.mounting``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from benchctl.config import BenchConfig, axis_map
from benchctl.errors import (
    DataError,
)
from benchctl.run import mounting as mt
from benchctl.run import prechecks as pc


def mounting_result(
    stand_rows: list[tuple[float, dict[str, float]]],
    samples: list[Any],
    axes: tuple[str, ...],
    cfg: BenchConfig,
) -> pc.CheckResult:
    """The mounting check's precheck from the tilt's stand samples ((t_host, angles) each) and
    instrument samples: the stand's measured angles interpolated at the instrument's instants,
    the response fitted and judged (``benchctl.run.mounting``)."""

    mc = cfg.run.mounting_check
    mapping = axis_map(cfg.instrument.axes)
    values: dict[str, Any] = {
        "axes": list(axes), "tilt_deg": mc.tilt_deg, "gain_tolerance": mc.gain_tolerance,
        "cross_tolerance": mc.cross_tolerance,
        "instrument_axes": {a: {"output": o, "sign": sg} for a, (o, sg) in mapping.items()},
    }
    name = "mounting"
    ts = np.array([t for t, _ in stand_rows], dtype=float)
    order = np.argsort(ts, kind="stable")
    readings = sorted({r for s in samples for r in s.angle_deg},
                      key=lambda r: (r not in axes, axes.index(r) if r in axes else 0, r))
    ti = np.array([s.t_host for s in samples], dtype=float)
    try:
        if not readings:
            raise DataError("mounting check: no instrument sample during the tilt")
        x = {a: np.array([stand_rows[i][1].get(a, math.nan) for i in order], dtype=float)
             for a in axes}
        y = {r: np.array([s.angle_deg.get(r, math.nan) for s in samples], dtype=float)
             for r in readings}
        resp, delay = mt.fit_sampled(ts[order], x, ti, y)
    except DataError as e:
        return pc.CheckResult(name, False, f"{e} (run.mounting_check)", values)
    values["response"] = resp.to_dict()
    values["delay_s"] = delay
    where = str(cfg.source) if cfg.source is not None else "the bench config"
    verdict = mt.judge(resp, axes, mapping, mc.gain_tolerance, mc.cross_tolerance, where)
    values["findings"] = {f.reading: f.kind for f in verdict.findings}
    if verdict.ok:
        seen = ", ".join(f"{r} {resp.gain[r][a]:.3f}× the stand's {a}"
                         for r in readings for a in axes if r == a)
        return pc.CheckResult(name, True, f"mounted as configured: {seen}", values)
    return pc.CheckResult(name, False, verdict.detail, values)
