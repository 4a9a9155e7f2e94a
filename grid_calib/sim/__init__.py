"""Simulated grid plate and stage for the grid self-calibration (tests and benches only)."""
