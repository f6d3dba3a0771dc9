"""Tests of autopilot/: control, estimation, identification, the commander's modes and
failsafes, navigation and flight tasks, the MAVLink server and its protocols, flown in
process on sim time."""
