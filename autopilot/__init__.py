"""Autopilot process: IVFM adaptive controller, MAVLink vehicle side, offline identification."""
