"""Conventions shared by every process: frames, units and (later) link contracts.

One place for each convention, so the simulator, the autopilot and the ground station
cannot disagree about what a number means.
"""

# The processes of a vehicle, as named in telemetry keys, perturbation targets and logs.
SITL, AUTOPILOT = "sitl", "autopilot"
