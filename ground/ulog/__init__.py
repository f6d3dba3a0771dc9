"""PX4 flight logs (ULog, read and written with pyulog, PX4's own parser): identification
data and draft airframes from a real vehicle's log (docs/px4-logs.md)."""
