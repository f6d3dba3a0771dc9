"""Regression checks: scenario files flown and judged (``checker``), their results as
JUnit, Markdown and a table (``results``), and the pytest plugin (``pytest_plugin``).
May import ``ground.run`` and the layers below it; not ``ground.campaign``."""
