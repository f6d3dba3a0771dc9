"""Reports of a run: metrics from its log, figures, the run's page (report.html) and the
report command's work (``run_report``). May import ``ground.record`` and
``ground.scenario``."""
