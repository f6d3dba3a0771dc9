"""The plant: quadrotor dynamics integrated at a fixed step (pure core + process shell)."""
