"""Simulated hardware shared by the machines (for tests and benchmarks only)."""
