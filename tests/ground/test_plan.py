"""QGroundControl .plan files (autopilot/navigator/plan_file.py, ground/uplink/plan.py):
read into mission, fence and rally lists, checked as the vehicle checks them, and uploaded
by ``ivfm plan`` to the real processes."""

from __future__ import annotations

import json

import pytest

from autopilot.navigator.mission_store import FENCE, MISSION, RALLY
from contracts.mavlink import mavlink
from ground.cli.main import main
from ground.uplink.plan import PlanError, read_plan
from tests.harness import GroundTool, start_processes

M = mavlink
LAT, LON = 47.397742, 8.545594


def _simple(command: int, jump_id: int, params: list, frame: int = 3) -> dict:
    return {"type": "SimpleItem", "autoContinue": True, "command": command,
            "doJumpId": jump_id, "frame": frame, "params": params}


def plan_data() -> dict:
    """What QGroundControl writes: a take-off, two waypoints, a jump back once, RTL; a fence
    polygon and circle; a rally point."""
    return {
        "fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 15,
                    "hoverSpeed": 5, "plannedHomePosition": [LAT, LON, 488],
                    "items": [
                        _simple(22, 1, [0, 0, 0, None, LAT, LON, 5]),
                        _simple(16, 2, [0, 1, 0, None, LAT + 2e-4, LON, 5]),
                        _simple(16, 3, [2, 1, 0, 90, LAT + 2e-4, LON + 3e-4, 6]),
                        _simple(177, 4, [2, 1, 0, 0, 0, 0, 0], frame=2),
                        _simple(20, 5, [0, 0, 0, 0, 0, 0, 0], frame=2)]},
        "geoFence": {"version": 2, "polygons": [
            {"inclusion": True, "version": 1, "polygon": [
                [LAT + 5e-4, LON + 5e-4], [LAT + 5e-4, LON - 5e-4], [LAT - 5e-4, LON - 5e-4],
                [LAT - 5e-4, LON + 5e-4]]}],
            "circles": [{"inclusion": False, "version": 1,
                         "circle": {"center": [LAT + 1e-4, LON], "radius": 4.0}}]},
        "rallyPoints": {"version": 2, "points": [[LAT - 1e-4, LON, 10]]},
    }


def test_a_plan_reads_into_the_three_lists(tmp_path):
    path = tmp_path / "mine.plan"
    path.write_text(json.dumps(plan_data()))
    lists = read_plan(path)
    mission = lists[MISSION]
    assert [i.command for i in mission] == [22, 16, 16, 177, 20]
    assert mission[3].params[0] == 1.0  # doJumpId 2 is item 1
    assert mission[2].params == (2.0, 1.0, 0.0, 90.0)
    assert mission[1].x == round((LAT + 2e-4) * 1e7) and mission[1].z == 5.0
    assert [i.command for i in lists[FENCE]] == [5001] * 4 + [5004]
    assert lists[FENCE][0].params[0] == 4.0 and lists[FENCE][4].params[0] == 4.0
    assert len(lists[RALLY]) == 1 and lists[RALLY][0].z == 10.0


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(fileType="Mission"), "not a QGroundControl plan"),
    (lambda d: d["mission"]["items"].append({"type": "ComplexItem", "complexItemType":
                                             "survey"}), "is a ComplexItem"),
    (lambda d: d["mission"]["items"][3]["params"].__setitem__(0, 9), "doJumpId 9"),
    (lambda d: d["mission"]["items"][1]["params"].__setitem__(4, 95.0), "latitude 95"),
    (lambda d: d["mission"]["items"][1].pop("params"), "needs command, frame and 7"),
    (lambda d: d["geoFence"]["circles"][0]["circle"].update(radius=0), "circle radius"),
])
def test_a_plan_the_vehicle_would_refuse_is_refused_before_upload(tmp_path, change, message):
    data = plan_data()
    change(data)
    path = tmp_path / "bad.plan"
    path.write_text(json.dumps(data))
    with pytest.raises(PlanError, match=message):
        read_plan(path)


def test_a_folder_named_as_the_plan_is_refused_naming_it(tmp_path):
    """The long fuzz run's find: a scenario's ``plan = ""`` named the scenario's folder,
    and reading it raised IsADirectoryError out of the scenario loader."""
    from ground.scenario.scenario_file import load_scenario

    with pytest.raises(PlanError, match="cannot read it: Is a directory"):
        read_plan(tmp_path)
    scenario = tmp_path / "s.toml"
    scenario.write_text('name = "s"\nduration_s = 5.0\n[mission]\nplan = ""\n')
    with pytest.raises(ValueError, match="cannot read it"):
        load_scenario(scenario)


@pytest.mark.process
def test_ivfm_plan_uploads_a_plan_that_the_vehicle_then_holds(tmp_path, capsys):
    path = tmp_path / "mine.plan"
    path.write_text(json.dumps(plan_data()))
    procs = start_processes(tmp_path)
    try:
        assert main(["plan", str(path), "--connect", f"udpin:127.0.0.1:{procs.gcs_port}"]) == 0
        out = capsys.readouterr().out
        assert "mission: 5 items uploaded" in out and "fence: 5 items uploaded" in out
        assert "rally points: 1 items uploaded" in out
        tool = GroundTool(procs.gcs_port)
        try:
            tool.connect()
            for mission_type, count in ((MISSION, 5), (M.MAV_MISSION_TYPE_FENCE, 5),
                                        (M.MAV_MISSION_TYPE_RALLY, 1)):
                tool.mav.mission_request_list_send(1, 1, mission_type)
                got = tool.wait_type("MISSION_COUNT", 5,
                                     lambda m, t=mission_type: m.mission_type == t)
                assert got.count == count
        finally:
            tool.close()
    finally:
        procs.stop()
