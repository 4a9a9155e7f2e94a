"""The simulated dispenser and its camera (tests and benches only)."""
