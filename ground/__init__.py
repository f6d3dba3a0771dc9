"""Ground-station side: scenarios, runs, metrics, reports and the ``ivfm`` command."""
