"""Benchmarks of engine (python -m benchmarks list)."""
