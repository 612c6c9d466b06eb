"""Benchmarks of sg (python -m benchmarks list)."""
