"""d2i's error against storage for two budget rules on one chart (issue 19, item 3): the
per-row energy tolerance (``truncate.budget: tolerance``, swept over
``truncate.tolerance``) and paper 000's proportional budgets (``truncate.budget:
proportional``, swept over ``truncate.coefficients``), from two ``prt evaluate`` runs of
the same scene and size:

    prt evaluate --method d2i --size 128x128 --reference-max-spp 1024 \\
        --sweep truncate.tolerance=0.01,0.02,0.05,0.1,0.2 --out T
    prt evaluate SCENE_WITH_PROPORTIONAL_BUDGET --method d2i --size 128x128 \\
        --reference-max-spp 1024 --sweep truncate.coefficients=25,50,100,150,250 --out P
    python studies/d2i_budget_chart.py T/results.json P/results.json --out DIR

Writes ``DIR/{surfaces,indirect}_error_vs_storage.png`` (pipeline/evaluation/charts.py's error
chart, one curve per rule) and ``DIR/results.json`` (both runs' records, relabelled).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from pipeline.evaluation.charts import CHARTS, error_chart


@click.command()
@click.argument("tolerance_results", type=click.Path(exists=True, path_type=Path))
@click.argument("proportional_results", type=click.Path(exists=True, path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(tolerance_results: Path, proportional_results: Path, out: Path) -> None:
    records = []
    for path, rule in ((tolerance_results, "tolerance budgets"),
                       (proportional_results, "paper's proportional budgets")):
        for record in json.loads(path.read_text()):
            records.append({**record, "method": f"d2i, {rule}"})
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(records, indent=1))
    _, label, _ = next(c for c in CHARTS if c[0] == "storage_bytes")
    for error in ("rel_rmse_surfaces", "rel_rmse_indirect"):
        name = error[len("rel_rmse_"):]
        click.echo(error_chart(records, "storage_bytes", label,
                               out / f"{name}_error_vs_storage.png", error))


if __name__ == "__main__":
    main()
