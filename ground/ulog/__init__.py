"""PX4's flight log format (ULog), in one place: the PX4 topics, field names, numbers and
parameter names the project uses (``px4_topics``), a run's records as PX4 topics and the
motor model behind actuator_motors (``run_topics``), and a run's MCAP log written as a
ULog that PX4's tools open (``export``). May import ``ground.record`` and
``ground.scenario``."""
