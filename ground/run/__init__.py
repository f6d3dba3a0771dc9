"""Flying a scenario: planned from its file and the overrides (``flights``), through the
three processes (``processes``) or in one (``inprocess``), with a progress line
(``progress``). May import the report, identify, telemetry and uplink layers and those
below them."""
