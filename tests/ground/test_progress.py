"""The progress line (ground/run/progress.py): live on a terminal, silent in logs, on an
injected clock."""

from __future__ import annotations

import io

from ground.run.progress import ProgressLine


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_on_a_terminal_the_line_shows_sim_time_speed_and_time_left():
    out, clock = Terminal(), Clock()
    line = ProgressLine("attitude-sine", 20.0, out, clock)
    line.loading()
    assert "loading the compiled numerical core" in out.getvalue()
    line.update(0.0)  # the first sim second: counted from here, not from loading
    clock.now += 2.0
    line.update(10.0)
    last = out.getvalue().split("\r\033[K")[-1]
    assert last == "attitude-sine:   10.0 of 20 s sim,   5.0x real time,    2 s left"
    clock.now += 0.05  # redrawn at most ten times a second
    line.update(10.2)
    assert out.getvalue().split("\r\033[K")[-1] == last
    line.done()
    assert out.getvalue().endswith("\r\033[K")


def test_in_a_log_nothing_is_printed():
    out, clock = io.StringIO(), Clock()
    line = ProgressLine("attitude-sine", 20.0, out, clock)
    line.loading()
    for t in range(20):
        clock.now += 1.0
        line.update(float(t))
    line.done()
    assert out.getvalue() == ""


def test_an_inprocess_run_keeps_the_first_steps_load_out_of_its_speed():
    from contracts.airframe import airframe_by_name
    from ground.report.metrics import compute_metrics
    from ground.run.inprocess import run_inprocess
    from ground.scenario.scenario_file import scenario_by_name

    heard: list[float] = []
    scenario = scenario_by_name("attitude-sine")
    record = run_inprocess(scenario, "smc", "paper", airframe_by_name("paper"),
                           progress=heard.append)
    assert heard == [round(0.1 * k, 10) for k in range(200)]  # every tenth of a second
    assert record.startup_wall_s > 0 and record.wall_time_s > 0
    assert compute_metrics(record, scenario, "paper")["startup_wall_s"] == \
        record.startup_wall_s


def test_a_live_line_logs_results_above_itself_and_only_results_in_a_log():
    """The one mechanism under every progress line (check, campaign, rehearsal)."""
    from ground.run.progress import LiveLine

    out, clock = Terminal(), Clock()
    line = LiveLine(out, clock)
    line.draw("[1/3] flying")
    clock.now += 0.05
    line.draw("[1/3] flying more", force=False)  # throttled: at most ten times a second
    line.log("[1/3] attitude-sine: pass")
    assert out.getvalue() == "\r\033[K[1/3] flying\r\033[K[1/3] attitude-sine: pass\n"
    line.clear()  # nothing live to clear after a logged line
    assert out.getvalue().endswith("pass\n")
    log = io.StringIO()
    quiet = LiveLine(log, clock)
    quiet.draw("[1/3] flying")
    quiet.log("[1/3] attitude-sine: pass")
    quiet.clear()
    assert log.getvalue() == "[1/3] attitude-sine: pass\n"
