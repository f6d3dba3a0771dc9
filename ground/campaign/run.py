"""Running a campaign on Dask distributed (docs/campaigns.md).

The client (``ivfm campaign``) turns the campaign into tasks, one per (scenario, draw,
controller) or, for an identification campaign, one per (seed, clusters), and sends
them to a Dask cluster in small batches: a LocalCluster sized to this machine by
default, or the scheduler given. Each task is a whole flight (in process, or through the
three processes) and gives one row.

Results stream into the campaign folder as tasks finish: ``runs/ID.json`` per run
(written whole, then renamed: a crash or Ctrl-C loses no finished run), and
``results.csv`` rebuilt from them at the end. A rerun of the same campaign into the same
folder skips every run that has its file. A run that fails (an exception, a divergence)
is a row with its reason; it never stops the campaign. A worker that dies mid-run has its
tasks redone elsewhere by Dask.

Each draw's scenario is written to ``draws/`` so that any run can be flown again alone:
``ivfm run DRAW.toml --controller C --seed S`` (the run's JSON gives the command).
"""

from __future__ import annotations

import csv
import functools
import json
import math
import os
import shutil
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import tomli_w

from autopilot.control.factory import load_models, model_airframe_metadata
from autopilot.identification.identify import identify_dataset
from autopilot.models.model_file import save_model
from contracts.airframe import PAPER, airframe_from_spec
from contracts.airframe_file import envelope_of, read_airframe
from contracts.atomic_file import atomic_writer, write_atomic
from ground.campaign.spec import Campaign
from ground.identify.excitation import excitation_dataset
from ground.report.metrics import compute_metrics
from ground.run.flights import Overrides, fly_processes, plan_flight
from ground.run.inprocess import run_inprocess
from ground.run.progress import LiveLine
from ground.scenario.scenario_file import load_scenario, scenario_by_name

RUNS_DIR, DRAWS_DIR, MODELS_DIR = "runs", "draws", "models"
RESULTS_FILE = "results.csv"
DEFAULT_CLUSTERS = 5


# -- tasks --------------------------------------------------------------------------------

def draw_scenario(campaign: Campaign, scenario_name: str, index: int,
                  values: dict[str, float], model_file: str | None) -> tuple[str, str]:
    """(file name, TOML text) of draw ``index`` of a scenario: the base scenario with the
    drawn plant perturbations over the whole run, its kicks and steps scaled, the model
    identified with the drawn seed, and no [expect] (the plant is not the one they were
    measured on)."""

    base = scenario_by_name(scenario_name)
    data = tomllib.loads(base.source.read_text())
    here = base.source.parent
    # Paths relative to the base file, made absolute: the draw lives in another folder.
    for table, key in (("mission", "plan"), ("controller", "model"), ("plant", "sensors")):
        value = data.get(table, {}).get(key)
        if isinstance(value, str) and (here / value).exists():
            data[table][key] = str((here / value).resolve())
    data.pop("expect", None)
    name = f"{base.name}-d{index:05d}"
    data["name"] = name
    data["description"] = (f"{base.description} (campaign {campaign.name}, draw {index}: "
                           + ", ".join(f"{k} {v:.4g}" for k, v in values.items()) + ")")
    if campaign.plant:
        data.setdefault("plant", {})["fidelity"] = campaign.plant
    entries = []
    for entry in data.get("perturbation", []):
        entry = dict(entry)
        if entry.get("kind") == "kick" and "kick_scale" in values:
            for field in ("phi_rad", "theta_rad"):
                if field in entry:
                    entry[field] = entry[field] * values["kick_scale"]
        if entry.get("kind") in ("mass", "inertia", "rotor_inertia") and \
                "perturbation_scale" in values:
            entry["scale"] = 1.0 + (entry["scale"] - 1.0) * values["perturbation_scale"]
        entries.append(entry)
    whole = {"start_s": 0.0, "end_s": float(data.get("duration_s", base.duration_s))}
    for factor, kind in (("mass_scale", "mass"), ("inertia_scale", "inertia"),
                         ("jr_scale", "rotor_inertia")):
        if factor in values:
            entries.append({"kind": kind, "scale": values[factor], **whole})
    for motor in range(1, 5):
        if f"motor_efficiency_{motor}" in values:
            entries.append({"kind": "motor_efficiency", "motor": motor,
                            "efficiency": values[f"motor_efficiency_{motor}"], **whole})
    if "wind_mps" in values:
        speed, heading = values["wind_mps"], values["wind_direction_rad"]
        entries.append({"kind": "wind", "ned_mps": [speed * math.cos(heading),
                                                    speed * math.sin(heading), 0.0], **whole})
    if "gust_mps" in values:
        speed, heading = values["gust_mps"], values["gust_direction_rad"]
        start = round(values["gust_start_fraction"] * whole["end_s"], 3)
        entries.append({"kind": "gust", "ned_mps": [speed * math.cos(heading),
                                                    speed * math.sin(heading), 0.0],
                        "start_s": start, "end_s": min(start + 2.0, whole["end_s"])})
    if entries:
        data["perturbation"] = entries
    if model_file is not None:
        data.setdefault("controller", {})["model"] = f"../{MODELS_DIR}/{model_file}"
    return f"{name}.toml", tomli_w.dumps(data)


def model_file_name(airframe: str, seed: int, clusters: int = DEFAULT_CLUSTERS) -> str:
    return f"{Path(airframe).stem}-seed{seed}-c{clusters}.json"


@functools.lru_cache(maxsize=64)  # ~50 KB each: every seed of a campaign, once per worker
def identified_model_json(airframe: str, seed: int, clusters: int = DEFAULT_CLUSTERS) -> str:
    """The model file's text of an identification with this excitation seed (kept per
    worker: every controller and scenario of a draw flies the same one)."""

    spec = read_airframe(airframe)  # once per worker and airframe (the cache above)
    dataset = excitation_dataset(airframe_from_spec(spec), seed=seed, envelope=envelope_of(spec))
    models = identify_dataset(dataset, n_clusters=clusters, seed=seed,
                              metadata=model_airframe_metadata(spec))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.json"
        save_model(path, models)
        return path.read_text()


def flight_tasks(campaign: Campaign) -> list[dict[str, Any]]:
    """Every task of a flight campaign, each draw's controllers together (pairs finish
    close in time)."""

    tasks = []
    for scenario_name in campaign.scenarios:
        airframe = scenario_by_name(scenario_name).airframe.argument  # tasks hold text
        for index in range(campaign.runs):
            values = campaign.draw(index)
            seed = values.get("identification_seed")
            model = None if seed is None else model_file_name(airframe, int(seed))
            draw_file, text = draw_scenario(campaign, scenario_name, index, values, model)
            for controller in campaign.controllers:
                tasks.append({
                    "id": f"{scenario_name}-d{index:05d}-{controller}",
                    "kind": "flights", "scenario": scenario_name, "draw": index,
                    "controller": controller, "values": values, "draw_file": draw_file,
                    "draw_toml": text, "model_file": model, "airframe": airframe,
                    "how": campaign.how, "plant": campaign.plant})
    return tasks


def identification_tasks(campaign: Campaign) -> list[dict[str, Any]]:
    """Seeds (the campaign's, then one per run) x cluster counts: a full grid."""
    return [{"id": f"s{campaign.seed + index:06d}-c{clusters}", "kind": "identification",
             "draw": index, "values": {"identification_seed": campaign.seed + index,
                                       "clusters": clusters}}
            for index in range(campaign.runs) for clusters in campaign.clusters]


def run_task(task: dict[str, Any]) -> dict[str, Any]:
    """One task, on a worker: its row (never raises: a failure is a row with its reason)."""
    start = time.perf_counter()
    row: dict[str, Any] = {"id": task["id"], "kind": task["kind"], "draw": task["draw"],
                           **task["values"], "error": "", "worker_pid": os.getpid()}
    try:
        if task["kind"] == "identification":
            row.update(_identify(task))
        else:
            row.update(_fly(task))
    except Exception as exc:  # noqa: BLE001 (a failed run is a result, not an end)
        row["error"] = f"{type(exc).__name__}: {exc}"[:500]
    row["wall_s"] = time.perf_counter() - start
    return row


def run_batch(tasks: list[dict[str, Any]], out_dir: str | None = None) -> list[dict[str, Any]]:
    """Several tasks on one worker, in turn. With ``out_dir`` (a folder the worker shares
    with the client: a LocalCluster), each run is saved there as soon as it is flown, so a
    Ctrl-C or a crash of the client loses no finished run of a batch still flying."""
    rows = []
    for task in tasks:
        row = run_task(task)
        if out_dir is not None and Path(out_dir).is_dir():
            save_row(Path(out_dir), task, dict(row))
        rows.append(row)
    return rows


def save_row(out_dir: Path, task: dict[str, Any], row: dict[str, Any]) -> None:
    """runs/ID.json, written whole then renamed (and the model a draw identified)."""
    model_json = row.pop("model_json", None)
    if model_json is not None:
        path = out_dir / MODELS_DIR / task["model_file"]
        if not path.exists():
            write_atomic(path, model_json)
    write_atomic(out_dir / RUNS_DIR / f"{row['id']}.json",
                 json.dumps(row, indent=1, default=float))


def batch_size(tasks: int, workers: int) -> int:
    """Up to 4 runs a batch, keeping at least 4 batches a worker (to balance the load)."""
    return max(1, min(4, tasks // max(1, 4 * workers)))


def _fly(task: dict[str, Any]) -> dict[str, Any]:

    out: dict[str, Any] = {"scenario": task["scenario"], "controller": task["controller"]}
    seed = int(task["values"].get("sensor_seed", 0))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / DRAWS_DIR).mkdir()
        draw = folder / DRAWS_DIR / task["draw_file"]
        write_atomic(draw, task["draw_toml"])
        if task["model_file"] is not None:
            (folder / MODELS_DIR).mkdir()
            seed_id = int(task["values"]["identification_seed"])
            text = identified_model_json(task["airframe"], seed_id)
            write_atomic(folder / MODELS_DIR / task["model_file"], text)
            out["model_json"] = text
        scenario = load_scenario(draw)
        plan = plan_flight(scenario, Overrides(controller=task["controller"],
                                               plant=task["plant"], seed=seed))
        if task["how"] == "processes":

            metrics = fly_processes(plan, folder / "run", figures=False, quiet=True)
        else:

            models = (load_models(plan.model_path, plan.airframe)
                      if plan.controller in ("ivfc", "t1fc") else None)
            record = run_inprocess(scenario, plan.controller, plan.plant,
                                   airframe_from_spec(plan.airframe), models,
                                   period_s=1.0 / plan.rate_hz, parameters=plan.parameters,
                                   sensors=plan.sensors, state_source=plan.state_source,
                                   seed=plan.seed, home=plan.home)
            metrics = compute_metrics(record, scenario, plan.airframe.argument)
    out["diverged"] = bool(metrics["diverged"])
    if out["diverged"]:
        out["error"] = "diverged: the vehicle left the flight envelope"
    for axis, m in metrics["axes"].items():
        out[f"{axis}_rmse"] = m["rmse"]
        out[f"{axis}_max_abs"] = m["max_abs"]
    control = metrics.get("control", {})
    out["effort"] = control.get("effort_mean_sum_c2")
    out["chattering_per_s"] = control.get("chattering_per_s")
    out["replay"] = (f"ivfm run {DRAWS_DIR}/{task['draw_file']} --controller "
                     f"{task['controller']} --seed {seed}"
                     + (" --inprocess" if task["how"] == "inprocess" else "")
                     + (f" --plant {task['plant']}" if task["plant"] else ""))
    return out


def _identify(task: dict[str, Any]) -> dict[str, Any]:

    values = task["values"]
    seed = int(values.get("identification_seed", 0))
    clusters = int(values.get("clusters", DEFAULT_CLUSTERS))
    dataset = excitation_dataset(PAPER, seed=seed)
    models = identify_dataset(dataset, n_clusters=clusters, seed=seed)
    out: dict[str, Any] = {"identification_seed": seed, "clusters": clusters}
    for name, ch in models.channels.items():
        out[f"{name}_ivfm_rmse"] = ch.rmse_valid_ivfm
        out[f"{name}_t1fm_rmse"] = ch.rmse_valid_t1fm
    return out


# -- the client -----------------------------------------------------------------------------

class CampaignProgress:
    """Runs done, failed, rate and time left: a live line on a terminal, a line per tenth
    of the campaign elsewhere."""

    def __init__(self, total: int, skipped: int, stream: Any = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.total, self.skipped = total, skipped
        self.out = LiveLine(stream, clock)
        self.clock = clock
        self.start = clock()
        self.done = self.failed = 0
        self._next_tenth = 1

    def line(self) -> str:
        elapsed = self.clock() - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        todo = self.total - self.skipped - self.done
        left = f"{todo / rate:.0f} s left" if rate > 0 else "time left unknown"
        return (f"campaign: {self.skipped + self.done}/{self.total} runs"
                + (f" ({self.skipped} from before)" if self.skipped else "")
                + f", {self.failed} failed, {rate:.2f} runs/s, {left}")

    def update(self, failed: bool) -> None:
        self.done += 1
        self.failed += failed
        if self.out.live:
            self.out.draw(self.line())
            return
        todo = self.total - self.skipped
        if todo and self.done * 10 >= self._next_tenth * todo:
            while self.done * 10 >= self._next_tenth * todo:
                self._next_tenth += 1
            self.out.log(self.line())

    def close(self) -> None:
        if self.out.shown:
            self.out.log(self.line())


def finished_ids(out_dir: Path) -> set[str]:
    return {p.stem for p in (out_dir / RUNS_DIR).glob("*.json")}


def read_rows(out_dir: Path) -> list[dict[str, Any]]:
    rows = []
    for path in sorted((out_dir / RUNS_DIR).glob("*.json")):
        try:
            rows.append(json.loads(path.read_text()))
        except (OSError, ValueError):
            continue  # a torn file from a crash of another kind: flown again next time
    return rows


def write_results(out_dir: Path) -> Path:
    """results.csv: one row per finished run, columns in a fixed order."""
    rows = read_rows(out_dir)
    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    path = out_dir / RESULTS_FILE
    with atomic_writer(path, text=True) as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)
    return path


def local_cluster(workers: int | None = None) -> Any:
    """A LocalCluster of one single-threaded worker process per CPU (the flights are
    CPU-bound Python: threads would share one interpreter lock)."""
    from dask.distributed import LocalCluster

    n = workers or len(os.sched_getaffinity(0))
    return LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=None, silence_logs=40)


def run_campaign(campaign: Campaign, out_dir: Path, scheduler: str | None = None,
                 workers: int | None = None, say: Callable[[str], None] | None = None,
                 stream: Any = None,
                 on_result: Callable[[dict[str, Any], Any], None] | None = None
                 ) -> dict[str, int]:
    """Fly every task not yet in ``out_dir``; returns counts (total, skipped, flown,
    failed). Ctrl-C stops it, keeping every finished run. ``on_result(row, client)``
    hears each row as it is saved."""
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise ValueError("ivfm campaign runs on Dask distributed, which is not installed: "
                         "pip install 'ivfm-sitl[cluster]' (or -e '.[cluster]' in the "
                         "repository)") from None

    say = say or (lambda text: print(f"ivfm: {text}", file=sys.stderr, flush=True))
    out_dir.mkdir(parents=True, exist_ok=True)
    for sub in (RUNS_DIR, DRAWS_DIR, MODELS_DIR):
        (out_dir / sub).mkdir(exist_ok=True)
    if campaign.source is not None:
        shutil.copyfile(campaign.source, out_dir / "campaign.toml")
    tasks = (identification_tasks(campaign) if campaign.kind == "identification"
             else flight_tasks(campaign))
    for task in tasks:  # every draw's scenario, for replays
        if "draw_file" in task and not (out_dir / DRAWS_DIR / task["draw_file"]).exists():
            write_atomic(out_dir / DRAWS_DIR / task["draw_file"], task["draw_toml"])
    done = finished_ids(out_dir)
    todo = [t for t in tasks if t["id"] not in done]
    counts = {"total": len(tasks), "skipped": len(tasks) - len(todo), "flown": 0, "failed": 0}
    if not todo:
        say(f"{campaign.name}: all {len(tasks)} runs are done already ({out_dir})")
        write_results(out_dir)
        return counts
    cluster = None
    if scheduler is None:
        cluster = local_cluster(workers)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    n_workers = len(client.scheduler_info()["workers"])
    say(f"{campaign.name}: {len(todo)} runs to fly ({counts['skipped']} done before) on "
        f"{n_workers} Dask worker(s) at {client.scheduler.address}; results in {out_dir}")
    progress = CampaignProgress(len(tasks), counts["skipped"], stream)
    # A few runs per Dask task: Dask's own cost per task (scheduler, client, messages)
    # is then paid once per batch (throughput 0.76 -> 0.82 of 2 x one plain process here).
    size = batch_size(len(todo), n_workers)
    batches = [todo[i:i + size] for i in range(0, len(todo), size)]
    shared = str(out_dir.resolve()) if scheduler is None else None  # workers see the folder
    futures = client.map(run_batch, batches, [shared] * len(batches), pure=False,
                         key=[f"{campaign.name}-{b[0]['id']}-x{len(b)}" for b in batches])
    batch_of = {f.key: b for f, b in zip(futures, batches, strict=True)}
    interrupted = False
    try:
        for future in as_completed(futures):
            batch = batch_of[future.key]
            try:
                rows = future.result()
            except Exception as exc:  # noqa: BLE001 (a task Dask gave up on: KilledWorker)
                rows = [{"id": t["id"], "kind": t["kind"], "draw": t["draw"], **t["values"],
                         "error": f"{type(exc).__name__}: {exc}"[:500]} for t in batch]
            for task, row in zip(batch, rows, strict=True):
                save_row(out_dir, task, row)
                counts["flown"] += 1
                counts["failed"] += bool(row.get("error"))
                progress.update(bool(row.get("error")))
                if on_result is not None:
                    on_result(row, client)
    except KeyboardInterrupt:
        interrupted = True
        client.cancel(futures)
        raise
    finally:
        progress.close()
        client.close()
        if cluster is not None:
            cluster.close()
        write_results(out_dir)
        if interrupted:  # counted on disk: workers save the runs they finish after Ctrl-C
            kept = len(finished_ids(out_dir)) - counts["skipped"]
            say(f"stopped: {kept} runs finished this time are kept; run the same command "
                "again to fly the rest")
    return counts
