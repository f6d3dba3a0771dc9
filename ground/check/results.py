"""What a check says: JUnit XML (one test case per expectation), the Markdown summary
for CI pages and the table on the terminal, from the scenarios' results."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable

from ground.check.checker import ScenarioResult
from ground.scenario.expectations import Outcome


def junit_suite(root: ET.Element, name: str, classname: str, outcomes: Iterable[Outcome],
                error: str | None, wall_time_s: float,
                failure_text: Callable[[Outcome], str] | None = None,
                **attributes: str) -> ET.Element:
    """One testsuite: a testcase per outcome (a failure says measured against limit), and
    first an error case when the flight itself failed; its counts set on it."""
    suite = ET.SubElement(root, "testsuite", name=name, time=f"{wall_time_s:.3f}",
                          **attributes)
    cases = failures = errors = 0
    if error is not None:
        case = ET.SubElement(suite, "testcase", classname=classname, name="flight")
        ET.SubElement(case, "error", message=error.splitlines()[0][:500],
                      type="FlightError").text = error
        cases, errors = 1, 1
    for o in outcomes:
        case = ET.SubElement(suite, "testcase", classname=classname, name=o.name)
        cases += 1
        if not o.passed:
            failures += 1
            ET.SubElement(case, "failure", message=o.message, type="ExpectationFailed"
                          ).text = failure_text(o) if failure_text else o.message
    suite.set("tests", str(cases))
    suite.set("failures", str(failures))
    suite.set("errors", str(errors))
    return suite


def junit_document(root: ET.Element, wall_time_s: float) -> str:
    """The testsuites' totals on the root, and the XML text."""
    for key in ("tests", "failures", "errors"):
        root.set(key, str(sum(int(s.get(key)) for s in root.iter("testsuite"))))
    root.set("time", f"{wall_time_s:.3f}")
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def junit_xml(results: list[ScenarioResult]) -> str:
    """JUnit XML: a testsuite per scenario, a testcase per expectation; a failure's
    message says the measured value against the limit."""
    root = ET.Element("testsuites", name="ivfm check")
    for r in results:
        suite = junit_suite(
            root, r.scenario.name, f"ivfm.check.{r.scenario.name}", r.outcomes, r.error,
            r.wall_time_s, lambda o, r=r: (f"{o.message}\nrun folder kept: {r.run_dir} "
                                           f"(ivfm report {r.run_dir})"),
            file=str(r.scenario.source))
        props = ET.Element("properties")
        ET.SubElement(props, "property", name="run_dir", value=str(r.run_dir))
        if r.metrics is not None and r.metrics.get("loop_real_time_factor"):
            ET.SubElement(props, "property", name="loop_real_time_factor",
                          value=f"{r.metrics['loop_real_time_factor']:.1f}")
        suite.insert(0, props)
    return junit_document(root, sum(r.wall_time_s for r in results))


def markdown_summary(results: list[ScenarioResult], wall_time_s: float) -> str:
    """A summary in GitHub's job summary Markdown ($GITHUB_STEP_SUMMARY)."""
    passed = sum(r.passed for r in results)
    lines = [f"## ivfm check: {passed} of {len(results)} scenarios passed "
             f"({wall_time_s:.1f} s)", "",
             "| scenario | result | expectations held | flight wall time | failures |",
             "|---|---|---|---|---|"]
    for r in results:
        held = sum(o.passed for o in r.outcomes)
        why = "; ".join(markdown_cell(o.message) for o in r.failures) if r.outcomes else ""
        if r.error:
            why = markdown_cell(r.error.splitlines()[0])
        mark = {"PASS": "✅ pass", "FAIL": "❌ fail", "ERROR": "💥 error"}[r.label]
        lines.append(f"| {r.scenario.name} | {mark} | {held} of {len(r.outcomes)} | "
                     f"{r.wall_time_s:.1f} s | {why} |")
    kept = [r for r in results if not r.passed]
    if kept:
        lines += ["", "Run folders of the failures (open with `ivfm report RUN_DIR`):", ""]
        lines += [f"* `{r.run_dir}`" for r in kept]
    return "\n".join(lines) + "\n"


def markdown_cell(text: str) -> str:
    """Text that stays in one Markdown table cell."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def results_table(results: list[ScenarioResult]) -> str:
    """The terminal's table: one row per scenario, then each failure on its own line."""
    width = max([8, *(len(r.scenario.name) for r in results)])
    lines = [f"{'scenario':<{width}}  result  held     wall"]
    for r in results:
        held = f"{sum(o.passed for o in r.outcomes)}/{len(r.outcomes)}"
        lines.append(f"{r.scenario.name:<{width}}  {r.label:<6}  {held:<7}  "
                     f"{r.wall_time_s:5.1f} s")
        for o in r.failures:
            lines.append(f"{'':<{width}}    x {o.name}: {o.message}")
        if r.error:
            lines.append(f"{'':<{width}}    x the flight failed: "
                         f"{r.error.splitlines()[0]}")
    return "\n".join(lines)
