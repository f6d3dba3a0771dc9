"""The ground's telemetry: the logger (Zenoh records into MCAP files, ``logger`` and
``mcap_file``), what Foxglove draws of them (``foxglove_view``) and the live view
(``live_view``), the .tlog export, the TLS test certificates. May import
``ground.record`` and ``ground.scenario``; never the vehicle's code, so the logger
starts fast."""
