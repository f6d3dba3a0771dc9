"""From a PX4 log to a rehearsal, as a person types it (docs/px4-logs.md): ``ivfm ulog
info``, ``ivfm airframe from-ulog``, the draft refused by ``ivfm rehearse`` until its
inertia is filled in, ``ivfm identify --ulog`` on the filled draft, and the rehearsal's
lockstep take-off and tracking flights with that model: a go. The log is the quad X 500's
excitation flown in process and logged as PX4 1.15 logs it (tests/ulog_logs.py)."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w

from contracts.airframe_file import read_airframe
from tests.ulog_logs import flight_log, lockstep_flight

pytestmark = pytest.mark.process

ROOT = Path(__file__).parents[2]
X500_INERTIA = "[[0.0217, 0.0, 0.0], [0.0, 0.0217, 0.0], [0.0, 0.0, 0.04]]"


def ivfm(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ground.cli", *argv], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_a_px4_log_to_a_draft_a_model_and_a_go(tmp_path):
    log = flight_log(tmp_path / "flight.ulg", lockstep_flight())
    info = ivfm("ulog", "info", str(log), cwd=ROOT)
    assert info.returncode == 0, info.stderr
    assert ("identification (ivfm identify --ulog): every signal is there; give --airframe "
            "to judge the reach against its envelope") in info.stdout

    draft = tmp_path / "my-quad.toml"
    made = ivfm("airframe", "from-ulog", str(log), "--mass-kg", "2.0", "--max-rad-s", "1000",
                "--out", str(draft), cwd=ROOT)
    assert made.returncode == 0, made.stderr
    assert made.stdout.splitlines()[:2] == [f"wrote {draft}",
                                            "fill in (marked TO_FILL): inertia_kgm2"]

    refused = ivfm("rehearse", "--airframe", str(draft), "--out", str(tmp_path / "r0"),
                   cwd=ROOT)
    assert refused.returncode == 2
    assert refused.stderr.strip() == (f"ivfm: error: airframe file {draft}: a draft airframe: "
                                      "fill in inertia_kgm2 (each marked \"TO_FILL\"; "
                                      "docs/px4-logs.md)")

    # The inertia, and the envelope this vehicle flies (the draft's commented table).
    text = draft.read_text()
    assert "# This log's flight reached 0.85 rad, 1.10 rad/s (roll, pitch), 1.52 rad/s (yaw)." \
        in text
    draft.write_text(text.replace('inertia_kgm2 = "TO_FILL"', f"inertia_kgm2 = {X500_INERTIA}")
                     .replace("# [envelope]", "[envelope]")
                     .replace("# attitude_rad", "attitude_rad")
                     .replace("# rate_rad_s", "rate_rad_s")
                     .replace("# yaw_rate_rad_s", "yaw_rate_rad_s"))
    model = tmp_path / "model.json"
    ident = ivfm("identify", "--ulog", str(log), "--airframe", str(draft), "--out", str(model),
                 cwd=ROOT)
    assert ident.returncode == 0, ident.stderr
    assert "(3800 samples every 0.01 s from 1 airborne span, 38.0 s)" in ident.stderr
    metadata = json.loads(model.read_text())["metadata"]
    assert metadata["airframe"] == "my-quad" and metadata["covered"] is True
    assert metadata["airframe_fingerprint"] == read_airframe(str(draft)).fingerprint()

    shipped = ROOT / "ground/rehearsal/profiles/default.toml"
    profile = tomllib.loads(shipped.read_text())
    profile["flight"] = [{**f, "scenario": str(shipped.parent / f["scenario"])}
                         for f in profile["flight"]
                         if f["scenario"].endswith(("takeoff-hold-land.toml", "tracking.toml"))]
    (tmp_path / "two.toml").write_text(tomli_w.dumps(profile))
    out = tmp_path / "rehearsal"
    go = ivfm("rehearse", "--airframe", str(draft), "--model", str(model), "--profile",
              str(tmp_path / "two.toml"), "--out", str(out), cwd=ROOT)
    assert go.returncode == 0, go.stdout + go.stderr
    assert go.stdout.startswith("rehearsal of my-quad: GO"), go.stdout
    result = json.loads((out / "rehearsal.json").read_text())
    assert [f["name"] for f in result["flights"]] == ["takeoff-hold-land", "tracking"]
    assert result["model"] == str(model)
