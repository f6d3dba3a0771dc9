"""Tests of contracts/: the conventions every process shares (airframe files, frames
and home, the paced loop, real-time statistics, Zenoh limits and security, CPUs kept
for the vehicle)."""
