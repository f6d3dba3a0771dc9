"""What a connected Foxglove viewer costs the vehicle: the autopilot's real-time timing with
and without one.

Flies ``ivfm run attitude-sine --realtime --rate-hz 250`` in pairs: one run without a
live view, one with ``--view`` and a WebSocket client subscribed to every channel
(tests/foxglove_client.py, as Foxglove's app subscribes), alternating so that a drift in
the machine's load falls on both. Prints each run's deadline misses, jitter p99 / max
and compute p99 (the autopilot's own figures, from run.json), the messages the viewer
received, and the medians of each side.

    python tests/benchmarks/bench_view.py --pairs 3

Asserts nothing: the figures are for docs/telemetry.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).parents[2]
sys.path.insert(0, str(ROOT))

from ground.run.children import free_tcp_port  # noqa: E402
from tests.foxglove_client import collect  # noqa: E402

FIGURES = ("deadline_misses", "jitter_p99_ms", "jitter_max_ms", "compute_p99_ms")


def fly(out: Path, view: bool, scenario: str, rate_hz: int) -> dict:
    argv = [sys.executable, "-m", "ground.cli", "run", scenario, "--realtime", "--rate-hz",
            str(rate_hz), "--no-figures", "--out", str(out)]
    received = {}
    watcher = None
    if view:
        port = free_tcp_port()
        argv += ["--view", f"127.0.0.1:{port}"]
        watcher = threading.Thread(target=lambda: received.update(
            got=collect(f"ws://127.0.0.1:{port}", seconds=600.0)), daemon=True)
        watcher.start()
    subprocess.run(argv, cwd=ROOT, check=True, capture_output=True, timeout=600)
    if watcher is not None:
        watcher.join(timeout=30)
    timing = json.loads((out / "run.json").read_text())["timing"]
    row = {k: timing[k] for k in FIGURES}
    row["viewer_messages"] = (sum(len(m) for m in received["got"].messages.values())
                              if view else 0)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--scenario", default="attitude-sine")
    parser.add_argument("--rate-hz", type=int, default=250)
    args = parser.parse_args()
    rows: dict[bool, list[dict]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.pairs):
            for view in (False, True):
                row = fly(Path(tmp) / f"{i}-{view}", view, args.scenario, args.rate_hz)
                rows[view].append(row)
                print(f"{'with viewer' if view else 'no viewer  '} pair {i + 1}: " +
                      "  ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                for k, v in row.items()), flush=True)
    for view in (False, True):
        medians = {k: statistics.median(r[k] for r in rows[view]) for k in FIGURES}
        print(f"median {'with viewer' if view else 'no viewer  '}: " +
              "  ".join(f"{k} {v:.3f}" for k, v in medians.items()))


if __name__ == "__main__":
    main()
