"""How benchmark results are printed: every figure whole, and the targets with met or not."""

from __future__ import annotations

import json

from arproj.bench import BenchTable, headline_table
from arproj.console import console


def _wide_table() -> BenchTable:
    columns = ["row"] + [f"figure number {k}" for k in range(16)]
    rows = [[f"case {r}"] + [0.001234567 * (k + 1) * (r + 1) for k in range(16)] for r in range(3)]
    headline = {
        "speed": {"arproj": 24.7, "peer": 101.5, "peer_name": "pyrender", "unit": " ms", "target": "≥ 5×",
                  "met": False},
        "error": {"arproj": 0.03, "peer": "–", "peer_name": "truth", "unit": " px", "target": "≤ 0.05 px",
                  "met": True},
    }
    return BenchTable(name="demo", title="a wide benchmark", columns=columns, rows=rows, notes=["a note"],
                      headline=headline)


def test_a_wide_table_prints_every_figure_whole_with_its_targets() -> None:
    table = _wide_table()
    with console.capture() as captured:
        table.print()
    text = captured.get()
    assert "…" not in text
    for value in (0.001234567 * 16 * 3, 0.001234567 * 7 * 2):
        assert f"{value:.3g}" in text  # whole numbers, on one line, however wide the table
    assert "a note" in text and "targets" in text
    target_rows = [line for line in text.splitlines() if "speed" in line or "error" in line]
    assert any("NO" in line and "101.5" in line for line in target_rows)
    assert any("yes" in line and "0.03 px" in line for line in target_rows)
    assert console.width == 150 or console.is_terminal  # the console's own width is left as it was


def test_targets_can_be_left_out_and_the_summary_names_each_benchmark() -> None:
    table = _wide_table()
    with console.capture() as captured:
        table.print(targets=False)
    assert "targets" not in captured.get()
    summary = headline_table([("demo", table.headline), ("other", {"x": {"arproj": 1, "met": None}})],
                             title="summary")
    assert summary.row_count == 3
    with console.capture() as captured:
        console.print(summary)
    text = captured.get()
    assert "demo" in text and "other" in text and "–" in text


def test_json_round_trip_keeps_the_table() -> None:
    table = _wide_table()
    again = BenchTable(**json.loads(table.to_json()))
    assert again == table


def test_a_quick_run_says_its_targets_are_only_indicative() -> None:
    table = _wide_table()
    with console.capture() as captured:
        table.print()
    assert "indicative" not in captured.get()
    table.environment["quick"] = True
    with console.capture() as captured:
        table.print()
    text = " ".join(captured.get().split())  # the title may wrap
    assert "indicative" in text and "judged on the full run" in text


def test_a_row_dataclass_gives_the_columns_and_cells_in_field_order() -> None:
    from dataclasses import dataclass

    from arproj.bench import cells, column, columns

    @dataclass
    class Row:
        case: str = column("case")
        mean_mm: float = column("mean mm", float("nan"))
        note: str = column("note", "")
        distance_m: float = 0.0  # for the headline only: not a column

    assert columns(Row) == ["case", "mean mm", "note"]
    table = BenchTable(name="t", title="t", columns=columns(Row), rows=[cells(Row("2 m", note="closed",
                                                                                distance_m=2.0))])
    (case, mean, note), = json.loads(table.to_json())["rows"]
    assert (case, note) == ("2 m", "closed") and mean != mean  # NaN: the default
