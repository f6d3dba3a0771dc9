"""Fuzzy models shipped with the autopilot (made by `ivfm identify --out`)."""
