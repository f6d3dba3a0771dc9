"""Scenarios: the scenario files (TOML, shipped in ``shipped/``), their expectations
(``[expect]``) and the scripted ground station a scenario may fly beside the vehicle
(``[ground_station]``). The bottom layer of ``ground/``: imports no other ground package
(only contracts, autopilot and sitl)."""
