"""Benchmarks of d2i (python -m benchmarks list)."""
