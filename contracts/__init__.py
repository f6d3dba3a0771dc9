"""Conventions shared by every process: frames, units and (later) link contracts.

One place for each convention, so the simulator, the autopilot and the ground station
cannot disagree about what a number means.
"""
