"""Tests of sitl/: the plant, the sensors, the simulator in process and over the
simulator link."""
