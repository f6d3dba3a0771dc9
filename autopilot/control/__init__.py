"""Controllers: the indirect adaptive fuzzy sliding-mode cascade and its baselines (pure)."""
