"""PX4's flight log format (ULog), in one place, read and written with pyulog (PX4's own
parser). Out: the PX4 topics, field names, numbers and parameter names the project writes
(``px4_topics``), a run's records as PX4 topics and the motor model behind
actuator_motors (``run_topics``), a run's MCAP log as a ULog PX4's tools open
(``export``; docs/ulog.md). In: every PX4 version's names and the reader (``read``), the
airborne spans on one clock (``clock``), identification data (``identification``), what
a log holds (``info``) and a draft airframe (``airframe_draft``; docs/px4-logs.md).
May import ``ground.record``, ``ground.scenario`` and ``ground.identify``."""
