"""A process's perturbations: the schedule it started with and the requests it has
taken since (add, clear, list), answered at the process's sim time.

The same book serves the simulator (plant and link kinds) and the autopilot (kicks), so
both answer a request the same way; a refused request changes nothing.
"""

from __future__ import annotations

import math
from typing import Any

from contracts.perturbations import Perturbation, parse_request, resolve_now

MAX_PERTURBATIONS = 1000  # per process: each step's cost grows with the count


class PerturbationBook:
    """A process's schedule: the entries it was started with plus those requested since.

    ``handle`` answers one request (``op`` add, clear or list) at sim time ``now_s`` or
    raises ValueError and changes nothing; ``changes`` says which entries started or ended
    since the last call, for the "applied at sim time" log.
    """

    def __init__(self, target: str, entries: tuple[Perturbation, ...] = ()) -> None:
        self.target = target
        self.entries: list[Perturbation] = [e for e in entries if e.target == target]
        self._active: set[str] = set()
        self._next_id = 0

    def handle(self, data: Any, now_s: float) -> dict[str, Any]:
        if not math.isfinite(now_s):  # sim time; "now" from an infinite clock is no time
            raise ValueError(f"the vehicle's clock reads {now_s!r}: no request is taken")
        if not isinstance(data, dict):
            raise ValueError("a request is a JSON object")
        data = dict(data)
        op = data.pop("op", "add")
        if op == "list":
            return {"perturbations": [e.to_request() for e in self.entries]}
        if op == "clear":
            return {"cleared": self._clear(data.get("id"), now_s)}
        if op != "add":
            raise ValueError(f"unknown op {op!r}; use add, clear or list")
        entry = self._accept(data, now_s)
        self.entries.append(entry)
        return entry.to_request()

    def _accept(self, data: dict[str, Any], now_s: float) -> Perturbation:
        if len(self.entries) >= MAX_PERTURBATIONS:
            raise ValueError(f"{MAX_PERTURBATIONS} perturbations already: every control step "
                             "looks at each, so no more are taken")
        entry = parse_request(data)
        if entry.target != self.target:
            raise ValueError(f"{entry.kind} acts in the {entry.target}, not the {self.target}")
        entry = resolve_now(entry, now_s)
        if entry.start_s < now_s:
            raise ValueError(f"start_s {entry.start_s:g} is in the past (sim time "
                             f"{now_s:.3f} s)")
        ids = {e.id for e in self.entries}
        if entry.id in ids:
            raise ValueError(f"a perturbation with id {entry.id!r} exists already")
        if not entry.id:
            while f"{self.target}-{self._next_id}" in ids:
                self._next_id += 1
            entry = Perturbation(entry.kind, entry.params, entry.start_s, entry.end_s,
                                 f"{self.target}-{self._next_id}")
        return entry

    def _clear(self, which: Any, now_s: float) -> list[str]:
        """End one perturbation (or all) now."""
        hits = [e for e in self.entries if which in (None, e.id) and e.end_s > now_s]
        if which is not None and not hits:
            raise ValueError(f"no perturbation with id {which!r} is pending or active")
        for e in hits:
            i = self.entries.index(e)
            self.entries[i] = Perturbation(e.kind, e.params, min(e.start_s, now_s), now_s, e.id)
        return [e.id for e in hits]

    def changes(self, t_s: float) -> list[tuple[str, Perturbation]]:
        """("start" | "end", entry) for entries that became active or ended by t."""
        active = {e.id for e in self.entries if e.active(t_s)}
        if active == self._active:
            return []
        out = [("start" if e.id in active else "end", e) for e in self.entries
               if (e.id in active) != (e.id in self._active)]
        self._active = active
        return out
