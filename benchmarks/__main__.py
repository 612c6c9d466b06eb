"""``python -m benchmarks list | run NAME... [--tiny] [--out DIR] [-- ARGS] | table``
(benchmarks/__init__.py)."""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import sys
from pathlib import Path

from benchmarks.fixtures import RESULTS, result_path

SUITES = ("engine", "d2i", "triple", "sg")


def benchmarks() -> dict[str, str]:
    """Every benchmark's name (``suite.name``) and the first line of its docstring."""
    found = {}
    for suite in SUITES:
        package = importlib.import_module(f"benchmarks.{suite}")
        for module in pkgutil.iter_modules(package.__path__):
            if module.name.startswith("_"):
                continue
            name = f"{suite}.{module.name}"
            doc = (importlib.import_module(f"benchmarks.{name}").__doc__ or "").strip()
            found[name] = doc.splitlines()[0] if doc else ""
    return found


def run(name: str, tiny: bool = False, out: Path | None = None,
        extra: list[str] = ()) -> dict:
    """Run benchmark ``name`` at its default (or tiny) preset plus ``extra`` options;
    its result (also written to ``out`` or benchmarks/results/<suite>/<name>.json)."""
    known = benchmarks()
    if name not in known:
        raise SystemExit(f"error: no benchmark {name!r} (python -m benchmarks list)")
    module = importlib.import_module(f"benchmarks.{name}")
    preset = module.PRESETS["tiny" if tiny else "default"]
    target = result_path(name, out / f"{name}.json" if out else None)
    return module.main([*preset, *extra, "--out", str(target)])


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    extra: list[str] = []
    if "--" in argv:
        extra = argv[argv.index("--") + 1:]
        argv = argv[:argv.index("--")]
    parser = argparse.ArgumentParser(prog="python -m benchmarks",
                                     description="The benchmark suite (benchmarks/__init__.py).")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("list", help="every benchmark, by suite")
    runner = commands.add_parser("run", help="run benchmarks by name")
    runner.add_argument("names", nargs="+", metavar="NAME")
    runner.add_argument("--tiny", action="store_true", help="the smoke size (seconds)")
    runner.add_argument("--out", type=Path, default=None,
                        help=f"folder for the results [default: {RESULTS}]")
    table = commands.add_parser("table", help="docs/results.md from the results")
    table.add_argument("--results", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.command == "list":
        for name, doc in benchmarks().items():
            print(f"{name:<24} {doc}")
    elif args.command == "run":
        for name in args.names:
            run(name, args.tiny, args.out, extra)
            print(json.dumps({"benchmark": name, "wrote": str(result_path(
                name, args.out / f"{name}.json" if args.out else None))}))
    else:
        from benchmarks.table import write_tables

        for path in write_tables(args.results):
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
