"""Loop statistics in fixed memory (contracts/realtime.py)."""

from __future__ import annotations

import numpy as np
import pytest

from contracts.realtime import BIN_S, BINS, Histogram, LoopTiming


def test_percentiles_match_numpy_within_a_bin() -> None:
    rng = np.random.default_rng(4)
    values = np.abs(rng.normal(0.0, 2e-4, 20_000)) + rng.exponential(5e-5, 20_000)
    h = Histogram()
    for v in values:
        h.add(float(v))
    for q in (50, 90, 99, 99.9):
        exact = float(np.percentile(values, q, method="inverted_cdf"))
        assert exact <= h.percentile(q) <= exact + BIN_S, q
    assert h.max_s == values.max()
    assert h.n == values.size and h.total_s == pytest.approx(values.sum())


def test_memory_does_not_grow_and_long_values_are_kept_as_the_maximum() -> None:
    h = Histogram()
    for k in range(100_000):
        h.add((k % 997) * 1e-6)
    h.add(0.2)  # 200 ms: past the last bin
    assert h.counts.shape == (BINS + 1,)
    assert h.counts.sum() == 100_001
    assert h.percentile(100) == pytest.approx(0.2)
    assert Histogram().percentile(50) != Histogram().percentile(50)  # NaN when empty


def test_loop_summary_in_milliseconds() -> None:
    timing = LoopTiming(0.004)
    for period in (0.004, 0.0041, 0.0039, 0.004, 0.0052):
        timing.record_period(period)
    for compute in (1e-4, 2e-4, 3e-4, 1e-4, 1e-4):
        timing.record_compute(compute)
    timing.misses = 1
    s = timing.summary()
    assert s["steps"] == 5 and s["deadline_misses"] == 1
    assert s["period_mean_ms"] == pytest.approx(4.24)
    assert s["jitter_max_ms"] == pytest.approx(1.2)
    # Percentiles are bin upper edges: at most one 1 us bin above the exact value.
    assert 0.1 - 1e-9 <= s["jitter_p50_ms"] <= 0.1 + BIN_S * 1e3 + 1e-9
    assert 0.3 - 1e-9 <= s["compute_p99_ms"] <= 0.3 + BIN_S * 1e3 + 1e-9
    assert LoopTiming(0.01).summary() == {"steps": 0, "deadline_misses": 0, "sim_stalls": 0,
                                          "sim_stall_steps": 0, "sim_stall_longest_ms": 0.0,
                                          "same_sample_held": 0}
    assert (s["sim_stalls"], s["sim_stall_steps"]) == (0, 0)


def test_stalls_count_episodes_steps_and_the_longest_gap() -> None:
    timing = LoopTiming(0.01)
    for new, gap_s in ((True, 0.021), (False, 0.031), (False, 0.041), (True, 0.025)):
        timing.record_stall(new, gap_s)
    s = timing.summary()
    assert (s["sim_stalls"], s["sim_stall_steps"]) == (2, 4)
    assert s["sim_stall_longest_ms"] == pytest.approx(41.0)
