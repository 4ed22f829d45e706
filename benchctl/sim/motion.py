"""The one simulated motion the simulated stand makes and the simulated instrument measures."""

from __future__ import annotations

from typing import Protocol


class MotionSource(Protocol):
    """Anything that knows the true stand angles at a host monotonic time ``t`` (seconds).

    The simulated stand implements it from its servo state history (so the instrument can look
    back by its own latency); tests may implement it with a closed-form motion.
    """

    def true_angles(self, t: float) -> dict[str, float]:
        """True angles in degrees by axis ("roll", "pitch") at monotonic time ``t``."""
        ...
