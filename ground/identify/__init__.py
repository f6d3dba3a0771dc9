"""Identification data from flights: the paper's excitation flown in process, a logged
flight turned into a dataset (``excitation``), and the paper's published tables.
May import ``ground.record`` and ``ground.scenario``."""
