"""What the Foxglove view costs the logger per control cycle: a real flight's records fed
to ``FoxgloveView`` and every message encoded, in thread CPU time, this checkout against
another (``--before``), alternately in the same minutes.

    python tests/benchmarks/bench_view_cost.py --before /path/to/older/checkout
    python tests/benchmarks/bench_view_cost.py --run runs/attitude-sine   # a flown run

Without ``--run`` it flies ``attitude-sine`` (20 s, lockstep, through the processes)
once. Each side runs in its own Python process, importing its own checkout; each round
gives the best of ``--repeats`` passes over the records. Prints the figures; asserts
nothing. The same bytes on both sides are checked by tests/ground/test_foxglove_view.py
and by ``python -m tests.lockstep_fingerprint``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

PASS = """
import sys, time
sys.path.insert(0, {root!r})
from pathlib import Path
from ground.record.run_files import iter_messages
from ground.telemetry.foxglove_scene import encode
from ground.telemetry.foxglove_view import FoxgloveView
records = [(topic, data) for topic, _m, data in iter_messages(Path({run!r}), "ivfm/")]
controls = sum(topic.endswith("/control") for topic, _ in records)

def feed():
    view = FoxgloveView()
    for key, data in records:
        for output in view.feed(key, data):
            encode(output.message)

feed()  # compiled code loaded, caches warm
best = float("inf")
for _ in range({repeats}):
    start = time.thread_time()
    feed()
    best = min(best, time.thread_time() - start)
print(best / controls * 1e6)
"""


def cost_us(root: Path, run: Path, repeats: int) -> float:
    """The view's CPU per control record (one 10 ms cycle at 100 Hz) with ``root``'s code."""
    out = subprocess.run([sys.executable, "-c", PASS.format(root=str(root), run=str(run),
                                                            repeats=repeats)],
                         capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", type=Path, help="another checkout's root")
    p.add_argument("--run", type=Path, help="a run folder with its log (default: fly one)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = args.run
        if run is None:
            run = Path(tmp) / "attitude-sine"
            subprocess.run([sys.executable, "-m", "ground.cli", "run", "attitude-sine",
                            "--no-figures", "--out", str(run)], cwd=ROOT, check=True,
                           capture_output=True)
        sides = {"this checkout": ROOT, **({str(args.before): args.before}
                                           if args.before else {})}
        costs: dict[str, list[float]] = {name: [] for name in sides}
        for _ in range(args.rounds):
            for name, root in sides.items():
                costs[name].append(cost_us(root, run, args.repeats))
        for name, values in costs.items():
            print(f"{name}: {statistics.median(values):.1f} us of CPU per 10 ms cycle "
                  f"(rounds: {', '.join(f'{v:.1f}' for v in values)})")


if __name__ == "__main__":
    main()
