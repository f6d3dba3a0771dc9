"""Many flights: campaigns of randomized draws on Dask (``spec``, ``run``, ``stats``,
``report``; shipped files in ``shipped/``) and the controller comparison (``compare``).
May import ``ground.run`` and the layers below it; not ``ground.check``."""
