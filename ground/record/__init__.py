"""What a run leaves on disk and reads back: the run folder's files and the MCAP log
read without Zenoh (``run_files``), the timeline of its processes (``timeline``), the
events in its log (``events``). May import ``ground.scenario``."""
