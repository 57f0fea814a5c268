"""Scan time and what the map then tells, adaptive plan vs the paper's dense raster, both mapped by `arproj map`'s
own path (mapping.pipeline.build_map) on hard-case walls and random walls (2.5 m × 2.0 m, simulated)."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from arproj.bench import BenchTable, cells, column, columns
from arproj.console import track

TARGET_TIME_RATIO_HARD = 0.25  # adaptive ≤ 1/4 of the dense raster's time on the hard-case walls
TARGET_TIME_RATIO_RANDOM = 0.2  # ... ≤ 1/5 on the random walls
TARGET_RECALL = 0.99  # pipes and cables, plain and as measured stretches (issues 15, 16)
TARGET_FALSE_SAFE = 0.0
TARGET_FASTENERS = 0.95
TARGET_AREAS = 0.90  # studs, plates (socket boxes), cavities
TARGET_DEPTH_MM = 5.0
PLANS = ("dense", "adaptive")  # the targets judge the adaptive plan against the dense raster
FINE_ROW_SPACING_M = 0.075  # a row sees a loose screw only within 39-47 mm: rows this close miss none
FINE = "adaptive, rows 7.5 cm"  # the adaptive plan with such rows (`arproj scan --row-spacing 0.075`), run too
RUNS = {"dense": ("dense", None), "adaptive": ("adaptive", None),
        FINE: ("adaptive", {"coarse_row_spacing_m": FINE_ROW_SPACING_M})}


@dataclass
class PlanStats:
    """One plan over one set of walls: scan times, the product's scores, the drill check's verdicts."""

    hours: list[float] = field(default_factory=list)
    passes: int = 0
    samples: int = 0
    found: int = 0
    targets: int = 0
    measured_found: int = 0  # targets found by the measured stretches of mapped lines alone
    errors_m: list[float] = field(default_factory=list)
    fasteners_found: int = 0
    fasteners: int = 0
    areas_found: int = 0
    areas_missed: list[str] = field(default_factory=list)  # kind (and material) of each missed area object
    areas: int = 0
    depth_errors_m: list[float] = field(default_factory=list)  # |mapped - true| of objects lying on a true one
    as_wood: list[str] = field(default_factory=list)  # "wall: id" of true pipes and cables labelled wood
    probed_m: float = 0.0
    safe_m: float = 0.0
    unknown_m: float = 0.0
    worst: tuple[str, float] = ("", 0.0)
    cpu_s: float = 0.0

    @property
    def recall(self) -> float:
        return self.found / self.targets if self.targets else float("nan")

    @property
    def measured_recall(self) -> float:
        return self.measured_found / self.targets if self.targets else float("nan")

    @property
    def fastener_recall(self) -> float:
        return self.fasteners_found / self.fasteners if self.fasteners else float("nan")

    @property
    def area_recall(self) -> float:
        return self.areas_found / self.areas if self.areas else float("nan")

    @property
    def depth_mm(self) -> float:
        return 1000 * float(np.mean(self.depth_errors_m)) if self.depth_errors_m else float("nan")

    @property
    def false_safe(self) -> float:
        return self.safe_m / self.probed_m if self.probed_m else 0.0

    @property
    def unknown(self) -> float:
        return self.unknown_m / self.probed_m if self.probed_m else 0.0


def _score(stats: PlanStats, wall, scan, result) -> None:
    from mapping.evaluate import (
        area_recall,
        depth_errors,
        evaluate,
        evaluate_measured,
        false_safe,
        fastener_recall,
        pipes_labelled_wood,
    )

    mapped = result.mapped_objects()
    ev = evaluate(result.objects, wall)
    stats.found += ev.n_found
    stats.targets += ev.n_targets
    stats.measured_found += evaluate_measured(mapped, wall).n_found
    stats.errors_m += list(ev.position_errors_m)
    found, total = fastener_recall(result.objects, wall)
    stats.fasteners_found += found
    stats.fasteners += total
    found, total, missed = area_recall(result.objects, wall)
    kinds = {o.id: f"{o.kind}{f' ({o.material})' if o.kind in ('stud', 'plate') else ''}" for o in wall.objects}
    stats.areas_missed += [kinds[i] for i in missed]
    stats.areas_found += found
    stats.areas += total
    stats.depth_errors_m += [abs(e) for _, e, _ in depth_errors(result.objects, wall)]
    stats.as_wood += [f"{wall.name}: {i}" for i in pipes_labelled_wood(result.objects, wall)]
    fs = false_safe(mapped, result.coverage, wall)
    stats.probed_m += sum(fs.probed_m.values())
    stats.safe_m += sum(fs.safe_m.values())
    stats.unknown_m += sum(fs.unknown_m.values())
    key, share = fs.worst()
    if share > stats.worst[1]:
        stats.worst = (f"{wall.name}: {key}", share)
    stats.hours.append(scan.scan_time_s / 3600)
    stats.passes += scan.n_passes
    stats.samples += len(scan.samples["time_s"])


@dataclass
class ScanRow:
    """One wall set × plan: mean scan time, passes and samples per wall, and the product's scores."""

    walls_plan: str = column("walls: plan")
    scan_time_h: float = column("scan time h")
    passes: float = column("passes")
    samples: float = column("samples")
    found: str = column("found")
    recall: float = column("recall")
    measured_found: str = column("measured found")
    measured_recall: float = column("measured recall")
    error_mm: float = column("error mm")
    fasteners: str = column("fasteners")
    areas: str = column("areas")
    area_recall: float = column("area recall")
    depth_mm: float = column("depth err mm")
    depth_n: int = column("depth n")
    as_wood: int = column("pipes as wood")
    false_safe_pct: float = column("false-safe %")
    unknown_pct: float = column("unknown %")
    cpu_s: float = column("cpu s / wall")


def _row(label: str, st: PlanStats) -> list:
    n = max(len(st.hours), 1)
    return cells(ScanRow(
        label, float(np.mean(st.hours)), st.passes / n, st.samples / n, f"{st.found}/{st.targets}", st.recall,
        f"{st.measured_found}/{st.targets}", st.measured_recall,
        float(np.mean(st.errors_m)) * 1000 if st.errors_m else float("nan"), f"{st.fasteners_found}/{st.fasteners}",
        f"{st.areas_found}/{st.areas}", st.area_recall, st.depth_mm, len(st.depth_errors_m), len(st.as_wood),
        100 * st.false_safe, 100 * st.unknown, st.cpu_s / n))


COLUMNS = columns(ScanRow)


def _worst(stats: dict[tuple[str, str], PlanStats], plan: str, figure: str, highest: bool = False) -> float:
    """The worst figure (an attribute of PlanStats) of `plan` over the wall sets: the lowest, or the highest
    (errors, shares called safe); NaN where no set has anything to score."""
    values = [getattr(st, figure) for (_, p), st in stats.items() if p == plan]
    values = [v for v in values if v == v]
    if not values:
        return float("nan")
    return max(values) if highest else min(values)


def _at_least(value: float, target: float) -> bool | None:
    return None if value != value else value >= target


def _time_ratio(stats: dict[tuple[str, str], PlanStats]) -> dict[str, float]:
    """Mean scan time of the adaptive plan over the dense raster's, per wall set."""
    return {name: float(np.mean(stats[(name, "adaptive")].hours)) / float(np.mean(stats[(name, "dense")].hours))
            for name, plan in stats if plan == "dense"}


def _headline(stats: dict[tuple[str, str], PlanStats]) -> dict[str, dict]:
    """The headline figures: the adaptive plan's (arproj) beside the dense raster's (peer) from the same run,
    each the worst over the wall sets, and the scan times per set."""
    peer = "dense raster 1 cm (paper), same mapping"
    hours = {key: float(np.mean(st.hours)) for key, st in stats.items()}
    ratio = _time_ratio(stats)

    def row(figure: str, unit: str, target: str, met: Callable[[float], bool | None], scale: float = 1.0,
            highest: bool = False, digits: int = 3) -> dict:
        ada = _worst(stats, "adaptive", figure, highest)
        dense = _worst(stats, "dense", figure, highest)
        return {"arproj": round(scale * ada, digits), "peer": round(scale * dense, digits), "peer_name": peer,
                "unit": unit, "target": target, "met": met(ada)}

    headline = {
        "false-safe length (adaptive)": row("false_safe", " %", "0.0 % on every wall",
                                            lambda v: v <= TARGET_FALSE_SAFE, scale=100, highest=True),
        "recall of pipes and cables (adaptive)": row("recall", "", f">= {TARGET_RECALL}",
                                                     lambda v: _at_least(v, TARGET_RECALL)),
        "recall of pipes and cables as measured stretches (adaptive)": row(
            "measured_recall", "", f">= {TARGET_RECALL}", lambda v: _at_least(v, TARGET_RECALL)),
        "recall of fasteners (adaptive)": row("fastener_recall", "", f">= {TARGET_FASTENERS}",
                                              lambda v: _at_least(v, TARGET_FASTENERS)),
        "recall of studs, plates (socket boxes), cavities (adaptive)": row(
            "area_recall", "", f">= {TARGET_AREAS}", lambda v: _at_least(v, TARGET_AREAS)),
        "depth error mean (adaptive)": row("depth_mm", " mm", f"<= {TARGET_DEPTH_MM} mm",
                                           lambda v: None if v != v else v <= TARGET_DEPTH_MM, highest=True,
                                           digits=2),
    }
    wood = {p: sum(len(st.as_wood) for (_, q), st in stats.items() if q == p) for p in PLANS}
    headline["pipes and cables labelled wood (adaptive)"] = {
        "arproj": wood["adaptive"], "peer": wood["dense"], "peer_name": peer, "unit": "", "target": "0",
        "met": wood["adaptive"] == 0}
    for name, target in (("hard-case", TARGET_TIME_RATIO_HARD), ("random", TARGET_TIME_RATIO_RANDOM)):
        if name in ratio:
            headline[f"scan time, {name} walls (adaptive / dense)"] = {
                "arproj": round(hours[(name, "adaptive")], 3), "peer": round(hours[(name, "dense")], 3),
                "peer_name": "dense raster 1 cm (paper)", "unit": " h", "target": f"ratio <= {target}",
                "met": ratio[name] <= target}
    return headline


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    """Adaptive plan vs dense raster: simulated scan time, recall (plain and as measured stretches), position
    and depth error, fasteners, studs, plates and cavities, pipes labelled wood and false-safe length of what
    `arproj map` makes of each scan."""
    from arproj.run.scan import scan_and_map
    from scanner.hard_walls import N_HARD_CASE_WALLS, hard_case_wall
    from scanner.wall import random_wall

    # --quick: 3 walls, the two judged plans only (the fine-row plan, not judged, cost a quarter of the run's
    # CPU: 119 s with it, ~85 s without, on a loaded machine), < 2 min
    n_hard = 2 if quick else N_HARD_CASE_WALLS
    n_random = 1 if quick else 6
    runs = {p: RUNS[p] for p in PLANS} if quick else RUNS
    sets = {"hard-case": [hard_case_wall(i, seed) for i in range(n_hard)],
            "random": [random_wall(seed * 1000 + i) for i in range(n_random)]}
    stats = {(name, plan): PlanStats() for name in sets for plan in runs}
    jobs = [(name, k, wall, plan) for name, walls in sets.items() for k, wall in enumerate(walls) for plan in runs]
    for name, k, wall, plan in track(jobs, "bench scan: scanning and mapping"):
        start = time.process_time()
        kind, options = runs[plan]
        scan, result = scan_and_map(wall, kind, seed * 1000 + k, options)
        st = stats[(name, plan)]
        _score(st, wall, scan, result)
        st.cpu_s += time.process_time() - start
    rows = [_row(f"{name}: {plan}", st) for (name, plan), st in stats.items()]
    ratio = _time_ratio(stats)
    worst_object, worst_share = max((stats[(n, p)].worst for n in sets for p in runs), key=lambda w: w[1])
    fine = {name: float(np.mean(stats[(name, FINE)].hours)) / float(np.mean(stats[(name, "dense")].hours))
            for name in sets if (name, FINE) in stats}
    as_wood = [f"{plan}: {w}" for (_, plan), st in stats.items() for w in st.as_wood]
    headline = _headline(stats)
    notes = [
        f"Walls: {n_hard} hard-case walls (scanner.hard_walls, seed {seed}: bends, detours between coarse rows, "
        f"junctions at socket boxes, crossings, parallel cables 5 cm apart, 5 cm deep and water-filled plastic "
        f"pipes, studs with fasteners, cavities) and {n_random} random walls (scanner.wall.random_wall); each "
        "scanned on the simulated site by both plans (scanner.run, in-process devices: the serial path gives the "
        "same samples) and mapped by mapping.pipeline.build_map, what `arproj map` runs.",
        "recall: cables and metal pipes <= 5 cm deep, found when >= 70 % of the centre line lies within 1.5 cm "
        "of a mapped line (mapping.evaluate). fasteners: a mapped fastener within 1.5 cm.",
        "false-safe: share of the length of every true metal pipe, cable and water-filled plastic pipe <= 5 cm "
        "deep, probed every 5 mm, that the drill check (mapping.drill, `arproj drill`) calls safe; unknown: the "
        "share it calls unknown (not scanned, inferred only, unexplained response).",
        "measured recall: the same rule against only the measured stretches of the mapped lines (objects.json's "
        "`measured` flags; a stretch joined across unmeasured ground is inferred and does not count; "
        "mapping.evaluate.evaluate_measured).",
        "areas: studs, beams, plates (socket and junction boxes) and cavities found when a mapped object of a "
        "class the channels can give them lies within 2 cm of the middle or holds it (mapping.evaluate."
        "area_recall). depth err: mean |mapped - true| depth of mapped objects with a depth lying on a true "
        "pipe, cable or fastener (depth n of them; mapping.evaluate.depth_errors).",
        "pipes as wood: true metal pipes, cables and water-filled plastic pipes <= 5 cm deep mostly covered by "
        "a non-metal outline (a stud's shape), or a metal one by anything non-metal "
        "(mapping.evaluate.pipes_labelled_wood)"
        + (f": {', '.join(as_wood)}." if as_wood else "; none."),
        "targets: each figure is the adaptive plan's worst over the wall sets (highest for false-safe and depth "
        "error), the peer the dense raster's the same way.",
        "areas missed: " + "; ".join(
            f"{name}: {plan}: " + (", ".join(f"{n} {k}" for k, n in sorted(Counter(st.areas_missed).items()))
                                   or "none")
            for (name, plan), st in stats.items() if st.areas) + ".",
        f"time ratio adaptive/dense: hard-case {ratio['hard-case']:.3f}, random {ratio['random']:.3f}.",
        f"'{FINE}': the adaptive plan with coarse rows {100 * FINE_ROW_SPACING_M:g} cm apart (`arproj scan "
        f"--row-spacing {FINE_ROW_SPACING_M}`), not judged: a row sees a screw or nail only within 39-47 mm of it "
        "(the sensor model, noise-free, at the planner's 0.10 peak threshold), so fasteners off every stud and "
        "course are found only with rows this close; "
        + (f"its time ratio to the dense raster: hard-case {fine['hard-case']:.3f}, random {fine['random']:.3f}."
           if fine else "run on the full run only (not with --quick)."),
        f"worst false-safe object: {worst_object or 'none'} ({100 * worst_share:.1f} % of its length).",
    ]
    return BenchTable(
        name="scan",
        title="arproj bench scan — adaptive plan vs dense raster, mapped by `arproj map` (2.5 m × 2.0 m, simulated)",
        columns=COLUMNS, rows=rows, notes=notes, headline=headline,
        environment={"quick": quick, "seed": seed, "hard_walls": n_hard, "random_walls": n_random,
                     "plans": list(runs), "time_ratio": ratio})
