"""``ivfm identify``: the IVFM and T1FM identified from input-output data (a flown
excitation, a dataset file or a logged flight), Table 2 printed beside the paper's."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from autopilot.control.factory import model_airframe_metadata
from autopilot.identification.coverage import coverage, coverage_metadata, format_coverage
from autopilot.identification.dataset import Dataset, read_dataset, write_dataset
from autopilot.identification.identify import DEFAULT_N_CLUSTERS, identify_dataset
from autopilot.models.model_file import save_model
from autopilot.models.ts_model import FuzzyModelSet
from contracts.airframe import Airframe, airframe_from_spec
from contracts.airframe_file import ENVELOPE_LIMITS, Envelope, envelope_of, spec_argument
from contracts.arguments import SEED, VEHICLE_ID, number
from ground.cli.common import UsageError
from ground.identify.excitation import MIN_SAMPLES, dataset_from_log, excitation_dataset
from ground.identify.paper_tables import TABLE_2_VALIDATION_RMSE
from ground.run.progress import ProgressLine
from ground.ulog.clock import DEFAULT_TRIM_S
from ground.ulog.identification import DEFAULT_CUTOFF_HZ, identification_data


def add_arguments(ident: argparse.ArgumentParser) -> None:
    ident.add_argument("--data", type=Path, help="dataset CSV (default: fly the excitation)")
    ident.add_argument("--log", type=Path, metavar="MCAP_OR_RUN_DIR",
                       help="identify from a logged flight (see docs/scenarios.md)")
    ident.add_argument("--ulog", type=Path, metavar="FLIGHT.ulg",
                       help="identify from a PX4 flight log (docs/px4-logs.md); give the "
                            "vehicle's --airframe")
    ident.add_argument("--vehicle", type=VEHICLE_ID, default=1, help="vehicle id in the log")
    ident.add_argument("--out", type=Path, default=None, help="model JSON to write")
    ident.add_argument("--write-data", type=Path, help="also save the generated excitation CSV")
    ident.add_argument("--seed", type=SEED, default=0)
    ident.add_argument("--samples", type=number(MIN_SAMPLES, 10_000_000, integer=True),
                       default=4000, help=f"excitation samples, at least {MIN_SAMPLES}")
    ident.add_argument("--clusters", type=number(2, 20, integer=True), default=None,
                       help="fuzzy clusters per model, 2-20 (default: the airframe's)")
    ident.add_argument("--airframe", default="paper", type=spec_argument,
                       help="shipped airframe name or airframe .toml file")
    ident.add_argument("--envelope", type=envelope_argument, default=None,
                       metavar="ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S]",
                       help="what the model will fly, which the data must cover; yaw rate "
                            "half the rate if not given (default: the airframe file's "
                            "[envelope], else 1 rad, 1 rad/s, 0.5 rad/s)")
    ident.add_argument("--allow-narrow", action="store_true",
                       help="write the model even if the data does not cover the envelope")
    ulog = ident.add_argument_group("with --ulog")
    add_ulog_arguments(ulog)


def add_ulog_arguments(p: argparse._ActionsContainer) -> None:
    """How a PX4 log becomes identification data (ivfm identify --ulog, ivfm ulog info)."""
    p.add_argument("--period-s", type=number(1e-4, 1.0, low_open=True), default=None,
                   help="the common clock's period (default: the body rates' own interval, "
                        "at least 0.01 s)")
    p.add_argument("--acc-cutoff-hz", type=number(0.0, 1e4), default=DEFAULT_CUTOFF_HZ,
                   help="low-pass of accelerations differentiated from the rates, applied to "
                        f"U alike; 0: none (default {DEFAULT_CUTOFF_HZ:g} Hz; unused when "
                        "the log has PX4's own derivative)")
    p.add_argument("--trim-s", type=trim_argument, default=DEFAULT_TRIM_S,
                   metavar="START[,END]",
                   help="seconds left out at the start and (before a landing) the end of "
                        "each airborne span (default "
                        f"{DEFAULT_TRIM_S[0]:g},{DEFAULT_TRIM_S[1]:g})")
    p.add_argument("--pwm-range", type=pwm_argument, default=None, metavar="MIN_US,MAX_US",
                   help="the PWM range of actuator_outputs, when the log's PWM_MAIN_MIN/MAX "
                        "are missing or wrong")


def trim_argument(text: str) -> tuple[float, float]:
    """START[,END] seconds, each in [0, 60]; END is START when not given."""
    parts = text.split(",")
    if len(parts) not in (1, 2):
        raise argparse.ArgumentTypeError(f"expected START[,END] seconds, got {text!r}")
    values = [number(0.0, 60.0, "s")(part.strip()) for part in parts]
    return (values[0], values[-1])


def pwm_argument(text: str) -> tuple[float, float]:
    """MIN_US,MAX_US: a PWM range in microseconds, MIN below MAX."""
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected MIN_US,MAX_US, got {text!r}")
    low, high = (number(0.0, 10_000.0, "us")(part.strip()) for part in parts)
    if not low < high:
        raise argparse.ArgumentTypeError(f"MIN_US must be below MAX_US, got {text!r}")
    return (low, high)


def envelope_argument(text: str) -> tuple[float, ...]:
    """ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S], each positive and bounded."""
    parts = text.split(",")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(
            f"expected ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S], got {text!r}")
    values = []
    for part, (name, high) in zip(parts, ENVELOPE_LIMITS.items(), strict=False):
        try:
            values.append(number(0.0, high, low_open=True)(part.strip()))
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{name} {exc}") from None
    return tuple(values) if len(values) == 3 else (*values, 0.5 * values[1])


def handle(args: argparse.Namespace) -> int:
    airframe = airframe_from_spec(args.airframe)
    envelope = Envelope(*args.envelope) if args.envelope else envelope_of(args.airframe)
    n_clusters = DEFAULT_N_CLUSTERS if args.clusters is None else args.clusters
    start = time.perf_counter()
    given = [name for name in ("data", "log", "ulog") if getattr(args, name) is not None]
    if len(given) > 1:
        both = " and ".join(f"--{name}" for name in given)
        raise UsageError(f"give one of --data, --log and --ulog, not {both}")
    if args.ulog is not None:
        dataset = ulog_dataset(args, airframe)
    elif args.log is not None:
        dataset = dataset_from_log(args.log, args.vehicle, airframe)
        print(f"ivfm: identifying from the log {args.log} ({dataset.n_rows} samples of "
              f"vehicle {args.vehicle})", file=sys.stderr)
    elif args.data is not None:
        dataset = read_dataset(args.data)
        print(f"ivfm: identifying from {args.data} ({dataset.n_rows} samples)", file=sys.stderr)
    else:
        print(f"ivfm: flying the excitation ({args.samples} samples, seed {args.seed}) for "
              f"the envelope {envelope.attitude_rad:g} rad, {envelope.rate_rad_s:g} rad/s "
              f"(yaw {envelope.yaw_rate_rad_s:g} rad/s)", file=sys.stderr)
        line = ProgressLine("  excitation", args.samples * 0.01)
        line.loading()
        try:
            dataset = excitation_dataset(airframe, n_samples=args.samples, seed=args.seed,
                                         progress=line.update, envelope=envelope)
        finally:
            line.done()
    if args.write_data is not None:
        write_dataset(args.write_data, dataset)
        print(f"wrote {args.write_data}")
    reach = coverage(dataset, envelope)
    print(format_coverage(reach))
    if not all(c.covered for c in reach):
        advice = ("the data does not cover the envelope: the model would extrapolate where "
                  "it is flown")
        if not args.allow_narrow:
            raise UsageError(f"{advice}. Fly a wider excitation, identify for the envelope "
                             f"the data covers (--envelope), or accept it (--allow-narrow); "
                             f"no model written")
        print(f"ivfm: warning: {advice} (--allow-narrow)", file=sys.stderr)
    models = identify_dataset(dataset, n_clusters=n_clusters, seed=args.seed,
                              metadata={**model_airframe_metadata(args.airframe),
                                        **coverage_metadata(envelope, reach)})
    elapsed = time.perf_counter() - start
    print(format_table_2(models, TABLE_2_VALIDATION_RMSE))
    print(f"identification took {elapsed:.2f} s")
    if args.out is not None:
        save_model(args.out, models)
        print(f"wrote {args.out}")
    return 0


def ulog_dataset(args: argparse.Namespace, airframe: Airframe) -> Dataset:
    """The identification data of ``--ulog``, saying where each signal came from."""
    data = identification_data(args.ulog, airframe, period_s=args.period_s,
                               cutoff_hz=args.acc_cutoff_hz, trim_s=args.trim_s,
                               pwm_range_us=args.pwm_range)
    seconds = sum(b - a for a, b in data.spans)
    print(f"ivfm: identifying from the PX4 log {args.ulog} ({data.dataset.n_rows} samples "
          f"every {data.period_s:g} s from {len(data.spans)} airborne span"
          f"{'s' if len(data.spans) != 1 else ''}, {seconds:.1f} s)", file=sys.stderr)
    for signal, text in data.sources.items():
        print(f"  {signal}: {text}", file=sys.stderr)
    for note in data.notes:
        print(f"ivfm: warning: {note}", file=sys.stderr)
    return data.dataset


def format_table_2(models: FuzzyModelSet, paper: dict[str, tuple[float, float]]) -> str:
    """The validation RMSE of each identified function beside the paper's Table 2."""
    lines = ["Validation RMSE of the identified models (paper's Table 2 beside ours)",
             f"{'function':<10}{'paper T1FM':>12}{'paper IVFM':>12}{'our T1FM':>12}"
             f"{'our IVFM':>12}  IVFM better?"]
    for name, ch in models.channels.items():
        p_t1, p_iv = paper[name]
        better = ch.rmse_valid_ivfm < ch.rmse_valid_t1fm
        verdict = "yes" if better else ("equal" if ch.rmse_valid_ivfm == ch.rmse_valid_t1fm
                                        else "no")
        lines.append(f"f_{name:<8}{p_t1:>12.4f}{p_iv:>12.4f}{ch.rmse_valid_t1fm:>12.4f}"
                     f"{ch.rmse_valid_ivfm:>12.4f}  {verdict}")
        lines.extend(f"    note: {note}" for note in ch.notes)
    return "\n".join(lines)
