"""The one way the vehicle says no: a reason a ground tool gets back (COMMAND_ACK result
and STATUSTEXT), and the range checks every request goes through."""

from __future__ import annotations

import math
from collections.abc import Iterable


class RefusedError(Exception):
    """A request the vehicle will not carry out, with the reason for the ground tool."""

    def __init__(self, reason: str, temporary: bool = False, failed: bool = False) -> None:
        super().__init__(reason)
        self.temporary = temporary  # MAV_RESULT_TEMPORARILY_REJECTED rather than DENIED
        self.failed = failed  # Copter answers FAILED (its check failed, not the request)


def check_finite(name: str, values: Iterable[float], limit: float) -> None:
    """Every value finite and within +-limit."""
    for v in values:
        if not math.isfinite(v):
            raise RefusedError(f"{name} holds NaN or infinity")
        if abs(v) > limit:
            raise RefusedError(f"{name} {v:g} is beyond +-{limit:g}")


def check_given(name: str, values: Iterable[float], limit: float) -> None:
    """NaN marks a left-out value here; what is given must be within +-limit."""
    for v in values:
        if math.isinf(v):
            raise RefusedError(f"{name} holds an infinity")
        if abs(v) > limit:
            raise RefusedError(f"{name} {v:g} is beyond +-{limit:g}")
