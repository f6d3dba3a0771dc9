"""The long fuzz run: every boundary's target (tests/fuzzing.py) for many more examples
than the CI run, printing each target's count and time.

    .venv/bin/python tests/stress/fuzz_long.py --examples 100000

Seeded and derandomized as the CI run is (the same first examples, then more); loopback
only. A failure prints hypothesis' smallest failing input and exits non-zero.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--examples", type=int, default=10_000,
                   help="examples per target (the log target runs a tenth: three commands each)")
    p.add_argument("-k", default=None, help="only the targets matching (pytest -k)")
    args = p.parse_args()
    env = {**os.environ, "FUZZ_EXAMPLES": str(args.examples)}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--durations=0",
           str(ROOT / "tests" / "test_fuzz.py")]
    if args.k:
        cmd += ["-k", args.k]
    print(f"fuzzing {args.examples} examples per target ...", flush=True)
    return subprocess.run(cmd, cwd=ROOT, env=env).returncode


if __name__ == "__main__":
    sys.exit(main())
