"""The simulated platform and laser tracker (tests, benches and sim nodes only)."""
