"""The frequency-response figure draws only the lines measured reliably (SNR ≥ 10): a sea
state's band-edge lines, 1e-8° high, read gains up to 1e10 and would set the gain's scale."""

from __future__ import annotations

import re

from benchctl.report.figures import frf_svg


def _analysis(reliable: list[bool] | None) -> dict[str, object]:
    gains = [2.2e4, 1.0e10, 0.995, 0.99, 0.98]
    return {"frf": {
        "freq": [0.05, 0.06, 0.1, 0.2, 0.3], "gain": gains, "phase_deg": [10.0, -50, -3, -6, -9],
        "coherence": [0.0, 0.0, 1.0, 1.0, 1.0],
        "gain_ci95": [[g * 0.9, g * 1.1] for g in gains],
        "phase_ci95_deg": [[-180, 180], [-180, 180], [-4, -2], [-7, -5], [-10, -8]],
        "reliable": reliable, "source": "lines"}, "periods": []}


def test_weak_lines_are_not_drawn_and_the_legend_says_so() -> None:
    svg = frf_svg(_analysis([False, False, True, True, True]))
    assert svg is not None
    assert "2 lines below the SNR floor not drawn" in svg
    # the gain axis spans the reliable lines' 0.98 … 0.995 (and gain = 1), not 1e10
    assert not re.search(r"10\^\{?10|1e\+?10|10000000000", svg)
    every = frf_svg(_analysis(None))  # H1 (no reliability test): every point drawn
    assert every is not None and "not drawn" not in every
    assert re.search(r"10\^\{?10|1e\+?10|10000000000", every)  # … where 1e10 sets the scale
    assert frf_svg(_analysis([False] * 5)) is None  # nothing measured reliably: no figure
