"""Benchmarks: one module per subject, each with `run(quick: bool = False, seed: int = 0) -> BenchTable`.

`arproj bench NAME` runs one (a module here is a benchmark by being here); `arproj bench all` runs them all.
Every benchmark runs its peer on the same input in the same run and reports the ratio.

Each reads as experiment → table → headline: the experiment measures and returns named figures; a table row is
a dataclass whose `column(header)` fields are the printed columns, in order (`columns(RowType)`, `cells(row)`);
the headline picks its figures from the rows by name.
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import inspect
import json
import pkgutil
import time
import tokenize
from collections.abc import Iterator
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from types import ModuleType
from typing import Any

from rich.measure import Measurement
from rich.table import Table

from arproj.console import console

# Quick runs take fewer trials: a target's "met" there is a hint, not the verdict.
QUICK_CAVEAT = " (--quick: indicative only, judged on the full run)"


def column(header: str, default: Any = MISSING) -> Any:
    """A field of a table row (a dataclass), printed under `header`; the row's other fields are not printed."""
    if default is MISSING:
        return field(metadata={"column": header})
    return field(default=default, metadata={"column": header})


def columns(row_type: type) -> list[str]:
    """The headers of a row dataclass's columns, in field order."""
    return [f.metadata["column"] for f in fields(row_type) if "column" in f.metadata]


def cells(row: Any) -> list[Any]:
    """A row dataclass's column values, in the order of `columns`."""
    return [getattr(row, f.name) for f in fields(row) if "column" in f.metadata]


@dataclass
class Stages:
    """Wall clock and CPU time (this process, all its threads) of a benchmark's stages, in the order run: where
    its time goes. On a loaded machine the CPU time is the steadier figure."""

    seconds: dict[str, dict[str, float]] = field(default_factory=dict)  # name -> {"wall", "cpu", "n"}

    @contextlib.contextmanager
    def stage(self, name: str, n: int = 1) -> Iterator[None]:
        """Time the block as stage `name` of n repeated units (the per-unit cost is cpu / n)."""
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.seconds[name] = {"wall": round(time.perf_counter() - wall, 2),
                                  "cpu": round(time.process_time() - cpu, 2), "n": n}

    def per_unit_cpu(self, name: str) -> float:
        """CPU seconds per unit of a stage (NaN when it did not run or had no units)."""
        s = self.seconds.get(name)
        return s["cpu"] / s["n"] if s and s["n"] else float("nan")

    def note(self) -> str:
        parts = [f"{name} {s['cpu']:.1f} s" + (f" ({s['cpu'] / s['n']:.2f} s × {s['n']:.0f})" if s["n"] > 1 else "")
                 for name, s in self.seconds.items()]
        total_cpu = sum(s["cpu"] for s in self.seconds.values())
        total_wall = sum(s["wall"] for s in self.seconds.values())
        return (f"time per stage, CPU (this process's threads): {'; '.join(parts)}; total {total_cpu:.0f} s CPU, "
                f"{total_wall:.0f} s wall")


@dataclass
class BenchTable:
    """A benchmark's result: a titled table, notes printed under it, and headline figures for `bench all`.

    headline: {label: {"arproj": value, "peer": value, "peer_name": str, "unit": str, "target": str,
    "met": bool | None}}
    """

    name: str
    title: str
    columns: list[str]
    rows: list[list[Any]]
    notes: list[str] = field(default_factory=list)
    headline: dict[str, dict[str, Any]] = field(default_factory=dict)
    environment: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        from geometry.plain import plain  # numpy: not for `arproj --help`

        return json.dumps(asdict(self), indent=2, default=plain)

    def print(self, targets: bool = True) -> None:
        """The table, its notes, then (targets=True) the headline figures: arproj, the peer, met or not."""
        table = Table(title=self.title, title_justify="left")
        for col in self.columns:
            # Figures wrap rather than end in "…" when the terminal is narrow: a cut number is a wrong one.
            table.add_column(col, justify="left" if col == self.columns[0] else "right", overflow="fold")
        for row in self.rows:
            table.add_row(*(_fmt(v) for v in row))
        # Not a terminal (a file, a CI log): as wide as the table needs.
        saved_width = console.width
        if not console.is_terminal:
            console.width = max(saved_width, Measurement.get(console, console.options.update_width(10_000),
                                                             table).maximum)
        try:
            console.print(table)
        finally:
            console.width = saved_width
        for note in self.notes:
            console.print(f"  {note}", highlight=False)
        if targets and self.headline:
            title = "targets" + (QUICK_CAVEAT if self.environment.get("quick") else "")
            console.print(headline_table([(self.name, self.headline)], title=title, with_benchmark=False))


def headline_table(sections: list[tuple[str, dict[str, dict[str, Any]]]], title: str,
                   with_benchmark: bool = True) -> Table:
    """Headline figures of one or more benchmarks ((name, headline) each) as a table: figure, arproj, peer
    (and what it is), target, met."""
    table = Table(title=title, title_justify="left")
    columns = ("benchmark", "figure", "arproj", "peer", "peer is", "target", "met")
    for col in columns if with_benchmark else columns[1:]:
        table.add_column(col, overflow="fold")
    for name, headline in sections:
        for label, h in headline.items():
            met = h.get("met")
            cells = [label, f"{h.get('arproj', '')}{h.get('unit', '')}", f"{h.get('peer', '–')}",
                     str(h.get("peer_name", "")), str(h.get("target", "")),
                     "–" if met is None else ("yes" if met else "NO")]
            table.add_row(*([name, *cells] if with_benchmark else cells))
    return table


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if v != v:  # NaN
            return "–"
        if abs(v) >= 1000:
            return f"{v:,.0f}"
        if abs(v) >= 100:
            return f"{v:.1f}"
        if abs(v) >= 1:
            return f"{v:.2f}"
        return f"{v:.3g}"
    if isinstance(v, bool):
        return "yes" if v else "NO"
    return str(v)


def benchmark_docs() -> dict[str, str]:
    """name -> docstring of every benchmark in this package, read from the source without importing it: the
    modules pull in scipy, OpenCV and GL, which `arproj --help` must not pay for."""
    docs = {}
    for m in pkgutil.iter_modules(__path__):
        if not m.name.startswith("_"):
            docs[m.name] = _docstring(Path(__path__[0]) / f"{m.name}.py") or m.name
    return docs


def _docstring(path: Path) -> str | None:
    """A module's docstring: its first token, if a string (parsing the whole file would cost 0.1 s for all)."""
    with path.open(encoding="utf-8") as file:
        for token in tokenize.generate_tokens(file.readline):
            if token.type in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.ENCODING):
                continue
            if token.type == tokenize.STRING:
                return inspect.cleandoc(ast.literal_eval(token.string))
            return None
    return None


def benchmark_modules() -> dict[str, ModuleType]:
    """name -> module for every benchmark in this package."""
    return {m.name: importlib.import_module(f"{__name__}.{m.name}")
            for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")}
