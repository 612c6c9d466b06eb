"""The benchmark suite: speed and accuracy measured in one run, written as JSON.

    python -m benchmarks list                    every benchmark, by suite
    python -m benchmarks run NAME [NAME ...]     run them at their default size
    python -m benchmarks run NAME --tiny         the smoke size (seconds; tests use it)
    python -m benchmarks run NAME -- ARGS        the benchmark's own options
    python -m benchmarks table                   docs/results.md from the results

A benchmark is a module ``benchmarks/<suite>/<name>.py`` (suites: ``engine``, ``d2i``,
``triple``, ``sg``) with ``main(argv) -> dict`` (its options parsed from ``argv``; it
writes its result to ``--out`` and returns it) and ``PRESETS = {"default": [...],
"tiny": [...]}``, the options of each size. What they share (baked scenes, the machine,
its load, medians, the bandwidth probe, result files) is in benchmarks/fixtures.py.
Results go to ``benchmarks/results/<suite>/<name>.json`` (outside git). One-off studies
that back a decision live in ``studies/``.
"""
