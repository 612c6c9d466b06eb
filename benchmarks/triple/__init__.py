"""Benchmarks of triple (python -m benchmarks list)."""
