"""Tests of ground/: scenarios and expectations, runs through the processes, the logger
and Foxglove, reports, checks, rehearsals, campaigns and the ivfm command."""
