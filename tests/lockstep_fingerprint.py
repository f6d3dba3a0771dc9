"""Fingerprints of lockstep logs: proof that a refactoring changed no flight.

A lockstep run through the processes is reproducible bit for bit, so the records its MCAP
log holds (everything but the wall-clock channels: loop timing and status; and Foxglove's
view of them, beside the records, the same way) hash to the
same digest run after run. Before a change meant to move nothing, save the digests of the
paper scenarios and the mission scenario; after it, compare:

    .venv/bin/python -m tests.lockstep_fingerprint --save /tmp/before.json
    .venv/bin/python -m tests.lockstep_fingerprint --compare /tmp/before.json

Each channel's digest covers every record's sim time, sequence and payload bytes; of a
MAVLink mirror frame, its message id and payload (the frame's sequence byte and checksum
count every message on a link, heartbeats sent in wall time among them; the mirror's
record sequence is shared by all its channels). Announcements and acknowledgements to
ground tools go out when the loop services its links, in wall time: of those, the texts
in their order.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

from mcap.reader import make_reader

# Channels carrying wall-clock readings (loop timing, status records with uptimes), and
# Foxglove's log of the vehicle's texts (stamped at wall-timed moments; its texts are the
# STATUSTEXT channel's, compared there).
WALL_CLOCK_SUFFIXES = ("/timing", "/status")
SKIPPED_TOPICS = ("/log",)
# Mirrored messages sent to ground tools at wall-clock moments.
WALL_TIMED_SUFFIXES = ("/STATUSTEXT", "/COMMAND_ACK")
SCENARIOS = ("attitude-sine", "attitude-hold", "position-sine", "attitude-jr-10",
             "attitude-jr-15", "attitude-jr-20", "position-kick", "mission-six-waypoints",
             "gps-outage", "x500-position-sine")


def mavlink_payload(frame: bytes) -> bytes:
    """A MAVLink frame's message id and payload, without sequence, checksum, signature."""
    length = frame[1]
    if frame[0] == 0xFD:  # v2: magic, len, incompat, compat, seq, sys, comp, msgid[3]
        return frame[7:10] + frame[10:10 + length]
    return frame[5:6] + frame[6:6 + length]  # v1: magic, len, seq, sys, comp, msgid


def log_digests(run_dir: Path) -> dict[str, str]:
    """{topic: sha256 of its records} of every MCAP file in ``run_dir``."""
    hashes: dict[str, hashlib._Hash] = {}
    records: dict[str, list[tuple[int, int, bytes]]] = {}
    for path in sorted(run_dir.glob("*.mcap")):
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
                if channel.topic.endswith(WALL_CLOCK_SUFFIXES) or \
                        channel.topic in SKIPPED_TOPICS:
                    continue
                time_ns, sequence, data = message.publish_time, message.sequence, message.data
                if channel.message_encoding == "mavlink":
                    data = mavlink_payload(data)
                records.setdefault(channel.topic, []).append((time_ns, sequence, data))
    for topic, rows in records.items():
        h = hashes.setdefault(topic, hashlib.sha256())
        mirrored, wall_timed = topic.startswith("mavlink/"), topic.endswith(WALL_TIMED_SUFFIXES)
        for time_ns, sequence, data in sorted(rows):
            if not wall_timed:
                h.update(time_ns.to_bytes(8, "little"))
            if not mirrored:
                h.update(sequence.to_bytes(4, "little"))
            h.update(data)
    return {topic: h.hexdigest() for topic, h in sorted(hashes.items())}


def fingerprint(names: tuple[str, ...] = SCENARIOS) -> dict[str, dict[str, str]]:
    """Fly each scenario through the processes in lockstep as ``ivfm run`` flies it (its
    own sensors, state source and parameters), forked by one process loader as ``ivfm
    run`` and ``ivfm check`` fly them, the simulator's sensor frames logged too;
    {scenario: {topic: digest}}."""
    from ground.run.flights import plan_flight
    from ground.run.loader import ProcessLoader
    from ground.run.processes import RunSettings, run_processes
    from ground.scenario.scenario_file import scenario_by_name

    out: dict[str, dict[str, str]] = {}
    loader = ProcessLoader()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for name in names:
                plan = plan_flight(scenario_by_name(name))
                settings = RunSettings(
                    plan.controller, plan.plant, plan.airframe.argument, plan.model_path,
                    {k: v for k, v in plan.parameters.items() if k in plan.given},
                    state_source=plan.state_source, sensors=plan.sensors, seed=plan.seed,
                    home=plan.home, log_sensors=True)
                run_dir = Path(tmp) / name
                run_processes(plan.scenario, settings, run_dir, quiet=True, loader=loader)
                out[name] = log_digests(run_dir)
                print(f"{name}: {len(out[name])} channels", file=sys.stderr, flush=True)
    finally:
        loader.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--save", type=Path, help="write the digests to this JSON file")
    action.add_argument("--compare", type=Path, help="compare with digests saved earlier")
    parser.add_argument("--scenario", action="append", help="only these scenarios")
    args = parser.parse_args(argv)
    names = tuple(args.scenario) if args.scenario else SCENARIOS
    digests = fingerprint(names)
    if args.save:
        args.save.write_text(json.dumps(digests, indent=1) + "\n")
        print(f"saved {len(digests)} scenarios to {args.save}")
        return 0
    saved = json.loads(args.compare.read_text())
    differ = [f"{name} {topic}" for name in names
              for topic in sorted(set(saved.get(name, {})) | set(digests[name]))
              if saved.get(name, {}).get(topic) != digests[name].get(topic)]
    for line in differ:
        print(f"DIFFERS {line}")
    print(f"{len(names)} scenarios: " + ("all logs identical" if not differ
                                         else f"{len(differ)} channels differ"))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
