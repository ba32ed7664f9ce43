#!/usr/bin/env python3
"""Check the result figures quoted in README.md against the runs that produce them.

    tools/readme_figures.py [--check]        run the configurations, compare, exit 1 on a drift
    tools/readme_figures.py --update         rewrite the quoted numbers in README.md that moved
    tools/readme_figures.py --runs sim_points,intel_walls   only those runs (what CTest does)
    tools/readme_figures.py --all            also the slow runs (the rendered ceiling route)
    tools/readme_figures.py --list           the runs and figures known, nothing is run

How it works
------------
The README stays the source of every number. A checked figure carries an HTML
comment right after it, which GitHub does not show:

    | mspace EKF | 0.059<!-- fig:sim.ate --> m | ... 1214<!-- fig:sim.created --> tentative created |

The comment must follow the number with no space between them; the number is
the run of digits (with an optional sign, decimals and space-grouped
thousands, "73 159") that ends where the comment starts. One id may be quoted
at several places (the sim ATE is in several tables); each place is checked at
its own precision. Anchors in code (fenced blocks, `spans`) are examples and
ignored; the numbers of a transcript in a code block are not checked.

This script holds the other half: for each id, which run measures it (RUNS:
the `mspace run` command line) and where the measurement is in that run's
summary.yaml (FIGURES: a dotted key, or a small function of the summary), and
the tolerance. Each run is executed once, and all its figures read from its
summary; a run that the README quotes nothing of is not run. An anchor whose id
is not in FIGURES is an error, so a typo cannot leave a figure unchecked;
`--list` shows which ids each run has quoted.

Tolerances. Every run here is deterministic (fixed seeds, a recorded log): on
one machine it reproduces bit for bit. So
  * counts (features, steps, fixes, …) must be equal;
  * a metric figure (metres, degrees, NEES) is OK when it is the measurement
    rounded to the digits the README shows, give or take METRIC_REL (0.01 %)
    of the figure — that slack is for another compiler or CPU (FMA or not) whose
    round-off moves a value that sits at a rounding boundary, not for changes.
Timings are never checked (they depend on the machine and its load), nor are
figures from one-off experiments that are not a run of a shipped
configuration (historical "before" columns, sweeps, other renderings).

A run whose data set is absent (Intel, Victoria Park under $MSPACE_DATA or
../shared/datasets) is skipped with a message; its figures are reported as
SKIP, not as a failure. Exit codes: 0 all checked figures agree, 1 a drift,
2 a usage, README or run error, 77 nothing could be checked (every selected
run skipped; CTest reports that as skipped).

--update writes the measurement into README.md at the precision and in the
format each place already uses, wherever the rounded measurement differs from
the text; run it after a change that moves the figures, review `git diff
README.md`, and commit it with the change.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path
from typing import Callable, Union

try:
    import yaml
except ImportError:  # Debian: python3-yaml (setup.sh installs it)
    print("readme_figures: PyYAML is not installed (apt install python3-yaml); nothing checked")
    sys.exit(77)

ROOT = Path(__file__).resolve().parent.parent
SKIPPED = 77
METRIC_REL = 1e-4  # see "Tolerances" above


# --------------------------------------------------------------------------
# The runs. `args` follow `mspace run`; --out and --quiet are added. `data` is
# the folder the run needs under the data root ($MSPACE_DATA, else
# ../shared/datasets from the project root); `slow` runs only with --all.


@dataclass
class Run:
    args: list[str]
    data: str | None = None
    generated: str | None = None  # a GENERATED input the run reads
    slow: bool = False


@dataclass
class Generated:
    """An input the script makes itself with a tool of the build, once per invocation: `command` ({bin}: the
    folder of the mspace binary, {dir}: where to write), and the variable the configurations read its folder from."""
    command: list[str]
    env: str


GENERATED: dict[str, Generated] = {
    # The rendered ceiling route of tests/ceiling_runs (seed 1): about 15 s of CPU, so its runs are slow.
    "ceiling_route": Generated(["{bin}/mspace-render-ceiling", "--out", "{dir}", "--seed", "1"], "MSPACE_CEILING"),
    # The building of the README's estimator table: plan ring, world seed 1, seed 1, default route (1 s).
    "building": Generated(["{bin}/mspace-sim-building", "--out", "{dir}", "--plan", "ring", "--world-seed", "1",
                           "--seed", "1", "--laser", "sick181"], "MSPACE_SIM_BUILDING"),
}


INTEL = "config/intel_walls.yaml"
VP = "config/victoria_park.yaml"
NN = ["--set", "association.method=nearest_neighbour"]
RUNS: dict[str, Run] = {
    "sim_points": Run(["config/sim_points.yaml"]),
    "sim_points.cekf": Run(["config/sim_points.yaml", "--estimator", "cekf"]),
    "sim_points.smoother": Run(["config/sim_points.yaml", "--estimator", "smoother"]),
    "intel_walls": Run([INTEL], data="intel_lab"),
    "intel_walls.nn": Run([INTEL, *NN], data="intel_lab"),
    "intel_walls.ekf": Run([INTEL, "--estimator", "ekf"], data="intel_lab"),
    "intel_walls.ekf_nn": Run([INTEL, "--estimator", "ekf", *NN], data="intel_lab"),
    "intel_walls.cekf": Run([INTEL, "--estimator", "cekf"], data="intel_lab"),
    "intel_walls.wheel": Run([INTEL, "--set", "source.odometry=wheel"], data="intel_lab"),
    "victoria_park": Run([VP], data="victoria_park"),
    "victoria_park.ekf": Run([VP, "--estimator", "ekf"], data="victoria_park"),
    "victoria_park.smoother": Run([VP, "--estimator", "smoother"], data="victoria_park"),
    "sim_building": Run(["config/sim_building.yaml"], generated="building"),
    "sim_building.ekf": Run(["config/sim_building.yaml", "--estimator", "ekf"], generated="building"),
    "sim_building.cekf": Run(["config/sim_building.yaml", "--estimator", "cekf"], generated="building"),
    **{f"ceiling_{c}": Run([f"config/ceiling_{c}.yaml"], generated="ceiling_route", slow=True)
       for c in ("lamps", "lines", "both", "fused")},
    **{f"ceiling_{c}.{e}": Run([f"config/ceiling_{c}.yaml", "--estimator", e], generated="ceiling_route", slow=True)
       for c in ("lines", "both", "fused") for e in ("cekf", "smoother")},
}


# --------------------------------------------------------------------------
# The figures. `measure` is a dotted key into summary.yaml or a function of
# the summary (a dict); `count` figures must match exactly, the others within
# the metric tolerance.

Measure = Union[str, Callable[[dict], float]]


@dataclass
class Figure:
    run: str
    measure: Measure
    count: bool = False


def mapped_features(s: dict) -> int:
    """Features in the map, all types, above M-space dimension 0 (those at 0 are still tentative)."""
    return sum(n for by_dim in s["features"].values() for dim, n in by_dim.items() if dim != "dim0")


def all_features(s: dict) -> int:
    """Features in the map, all types and M-space dimensions."""
    return sum(n for by_dim in s["features"].values() for n in by_dim.values())


def features_at(dim: int, kind: str | None = None) -> Callable[[dict], int]:
    """Features at one M-space dimension, of every type or of one (`kind`, as summary.yaml names it)."""
    return lambda s: sum(by_dim.get(f"dim{dim}", 0) for k, by_dim in s["features"].items() if kind in (None, k))


def features_of(kind: str) -> Callable[[dict], int]:
    """Features of one type, at any M-space dimension."""
    return lambda s: sum(s["features"].get(kind, {}).values())


def trajectory(prefix: str, run: str, section: str = "ground_truth") -> dict[str, Figure]:
    """A run's figures against its reference, as ids `prefix.ate`, `prefix.final`, …"""
    return {
        f"{prefix}.ate": Figure(run, f"{section}.ate_rmse_m"),
        f"{prefix}.median": Figure(run, f"{section}.ate_median_m"),
        f"{prefix}.max": Figure(run, f"{section}.ate_max_m"),
        f"{prefix}.final": Figure(run, f"{section}.final_translation_error_m"),
        f"{prefix}.heading": Figure(run, f"{section}.final_heading_error_deg"),
        f"{prefix}.nees": Figure(run, "ground_truth.mean_robot_nees"),
    }


def relations(prefix: str, run: str, section: str = "relations") -> dict[str, Figure]:
    """Relation errors, mean and standard deviation: `prefix.t`, `prefix.t_std`, `prefix.r`, `prefix.r_std`."""
    return {
        f"{prefix}.t": Figure(run, f"{section}.translation_m.mean"),
        f"{prefix}.t_std": Figure(run, f"{section}.translation_m.std"),
        f"{prefix}.r": Figure(run, f"{section}.rotation_deg.mean"),
        f"{prefix}.r_std": Figure(run, f"{section}.rotation_deg.std"),
    }


FIGURES: dict[str, Figure] = {
    # The built-in simulated world (config/sim_points.yaml, ekf) and its estimator variants.
    **trajectory("sim", "sim_points"),
    **trajectory("sim.dr", "sim_points", "dead_reckoning.ground_truth"),
    "sim.steps": Figure("sim_points", "steps", count=True),
    "sim.state_dim": Figure("sim_points", "state_dimension", count=True),
    "sim.features": Figure("sim_points", mapped_features, count=True),
    "sim.created": Figure("sim_points", "counts.features_created", count=True),
    "sim.pruned": Figure("sim_points", "counts.tentative_pruned", count=True),
    **trajectory("sim.cekf", "sim_points.cekf"),
    **trajectory("sim.smoother", "sim_points.smoother"),
    # Intel (config/intel_walls.yaml: smoother, JCBB, shared corners) and the rows beside it.
    **trajectory("intel", "intel_walls"),
    **relations("intel.rel", "intel_walls"),
    "intel.scans": Figure("intel_walls", "steps", count=True),
    "intel.rel.matched": Figure("intel_walls", "relations.matched", count=True),
    "intel.loop.searches": Figure("intel_walls", "association.loop_closing.searches", count=True),
    **trajectory("intel.dr", "intel_walls", "dead_reckoning.ground_truth"),
    **relations("intel.dr.rel", "intel_walls", "dead_reckoning.relations"),
    **trajectory("intel.nn", "intel_walls.nn"),
    **relations("intel.nn.rel", "intel_walls.nn"),
    **trajectory("intel.ekf", "intel_walls.ekf"),
    **relations("intel.ekf.rel", "intel_walls.ekf"),
    **trajectory("intel.cekf", "intel_walls.cekf"),
    **relations("intel.cekf.rel", "intel_walls.cekf"),
    **trajectory("intel.ekf_nn", "intel_walls.ekf_nn"),
    **relations("intel.ekf_nn.rel", "intel_walls.ekf_nn"),
    "intel.ekf_nn.walls": Figure("intel_walls.ekf_nn", all_features, count=True),
    **{f"intel.ekf_nn.walls_dim{d}": Figure("intel_walls.ekf_nn", features_at(d), count=True) for d in (0, 2, 3, 4)},
    "intel.ekf_nn.corners": Figure("intel_walls.ekf_nn", "counts.shared_coordinates", count=True),
    **trajectory("intel.wheel", "intel_walls.wheel"),
    **relations("intel.wheel.rel", "intel_walls.wheel"),
    **trajectory("intel.wheel.dr", "intel_walls.wheel", "dead_reckoning.ground_truth"),
    **relations("intel.wheel.dr.rel", "intel_walls.wheel", "dead_reckoning.relations"),
    # Victoria Park (config/victoria_park.yaml: cekf) and the other estimators.
    **trajectory("vp", "victoria_park"),
    **trajectory("vp.dr", "victoria_park", "dead_reckoning.ground_truth"),
    "vp.fixes": Figure("victoria_park", "ground_truth.poses_compared", count=True),
    "vp.steps": Figure("victoria_park", "steps", count=True),
    "vp.poles": Figure("victoria_park", mapped_features, count=True),
    **trajectory("vp.ekf", "victoria_park.ekf"),
    "vp.ekf.poles": Figure("victoria_park.ekf", mapped_features, count=True),
    **trajectory("vp.smoother", "victoria_park.smoother"),
    # The rendered ceiling route (--all): features of the configurations' maps.
    "ceiling.lamps.lamps": Figure("ceiling_lamps", features_of("lamp"), count=True),
    "ceiling.both.lamps": Figure("ceiling_both", features_of("lamp"), count=True),
    "ceiling.fused.lamps": Figure("ceiling_fused", features_of("lamp"), count=True),
    "ceiling.fused.walls": Figure("ceiling_fused", features_of("wall"), count=True),
    **{f"ceiling.{c}.lines_dim{d}": Figure(f"ceiling_{c}", features_at(d, "line"), count=True)
       for c in ("lines", "both", "fused") for d in (1, 3)},
}
# The generated building (config/sim_building.yaml: the smoother) and the filters.
for est in ("", ".ekf", ".cekf"):
    FIGURES.update(trajectory(f"building{est}", f"sim_building{est}"))
    FIGURES.update(relations(f"building{est}.rel", f"sim_building{est}"))
# The rendered ceiling route: the configurations, with other estimators but for the lamps.
FIGURES.update(trajectory("ceiling.odometry", "ceiling_lines", "dead_reckoning.ground_truth"))
for c in ("lamps", "lines", "both", "fused"):
    for est in ("",) if c == "lamps" else ("", ".cekf", ".smoother"):
        FIGURES.update(trajectory(f"ceiling.{c}{est}", f"ceiling_{c}{est}"))


# --------------------------------------------------------------------------
# Reading the README.

NUMBER = r"[-−]?(?:\d{1,3}(?: \d{3})+|\d+)(?:\.\d+)?"
ANCHOR = re.compile(r"<!-- fig:([\w.\-]+) -->")
NUMBER_AT_END = re.compile(NUMBER + r"$")


@dataclass
class Quote:
    """One quoted figure: where it is in the README text and how it is written."""
    fig_id: str
    start: int  # offset of the number in the README
    end: int
    text: str
    line: int

    @property
    def value(self) -> Decimal:
        return Decimal(self.text.replace(" ", "").replace("−", "-"))

    @property
    def decimals(self) -> int:
        return len(self.text.split(".")[1]) if "." in self.text else 0

    def format(self, measured: float) -> str:
        """The measurement written as this quote is: same decimals, grouping, minus sign."""
        q = Decimal(repr(measured)).quantize(Decimal(1).scaleb(-self.decimals), rounding=ROUND_HALF_EVEN)
        if q == 0:
            q = abs(q)
        body = f"{abs(q):,.{self.decimals}f}" if " " in self.text else f"{abs(q):.{self.decimals}f}"
        body = body.replace(",", " ")
        if q < 0:
            body = ("−" if "−" in self.text else "-") + body
        return body


def in_code(readme: str, pos: int) -> bool:
    """Whether pos is inside a fenced code block or an inline `code span` (where an anchor is an example)."""
    line_start = readme.rfind("\n", 0, pos) + 1
    fences = sum(1 for line in readme[:line_start].split("\n") if line.startswith("```"))
    return fences % 2 == 1 or readme[line_start:pos].count("`") % 2 == 1


def find_quotes(readme: str) -> list[Quote]:
    quotes = []
    for m in ANCHOR.finditer(readme):
        if in_code(readme, m.start()):
            continue
        line = readme.count("\n", 0, m.start()) + 1
        before = readme[max(0, m.start() - 40):m.start()]
        n = NUMBER_AT_END.search(before)
        if not n:
            raise SystemExit(f"README.md:{line}: anchor fig:{m.group(1)} does not follow a number")
        start = m.start() - (len(before) - n.start())
        quotes.append(Quote(m.group(1), start, m.start(), n.group(0), line))
    return quotes


# --------------------------------------------------------------------------
# Running and measuring.


def data_root() -> Path:
    return Path(os.environ.get("MSPACE_DATA") or ROOT.parent / "shared" / "datasets").resolve()


def generate(key: str, mspace: Path, work: Path) -> Path:
    """Make a GENERATED input under work (once: a second run that needs it finds it there)."""
    folder = work / f"input_{key}"
    if not folder.is_dir():
        cmd = [c.format(bin=mspace.parent, dir=folder) for c in GENERATED[key].command]
        print(f"generate {key}: {' '.join(cmd)}", flush=True)
        done = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if done.returncode != 0:
            print(done.stdout)
            raise SystemExit(f"readme_figures: generating {key} failed with exit code {done.returncode}")
    return folder


def execute(name: str, run: Run, mspace: Path, work: Path) -> dict | str:
    """Run one configuration; its summary, or the reason it was skipped."""
    env = dict(os.environ, MSPACE_DATA=str(data_root()))
    if run.data and not (data_root() / run.data).is_dir():
        return f"data set {data_root() / run.data} absent (set MSPACE_DATA)"
    if run.generated:
        env[GENERATED[run.generated].env] = str(generate(run.generated, mspace, work))
    out = work / name
    cmd = [str(mspace), "run", *run.args, "--out", str(out), "--quiet"]
    print(f"run {name}: {' '.join(cmd)}", flush=True)
    done = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if done.returncode != 0:
        print(done.stdout)
        raise SystemExit(f"readme_figures: run {name} failed with exit code {done.returncode}")
    with open(out / "summary.yaml") as f:
        return yaml.safe_load(f)


def measure(fig: Figure, summary: dict) -> float:
    if callable(fig.measure):
        return fig.measure(summary)
    value = summary
    for key in fig.measure.split("."):
        if not isinstance(value, dict) or key not in value:
            raise SystemExit(f"readme_figures: {fig.run}'s summary.yaml has no {fig.measure}")
        value = value[key]
    return value


def tolerance(fig: Figure, quote: Quote) -> float:
    """Largest |measured − quoted| accepted at this quote."""
    if fig.count:
        return 0.0
    half_unit = 0.5 * 10.0 ** -quote.decimals
    return half_unit + METRIC_REL * abs(float(quote.value))


def describe_tolerance(fig: Figure, quote: Quote) -> str:
    if fig.count:
        return "exact"
    return f"±{0.5 * 10.0 ** -quote.decimals:g} +{METRIC_REL:.2%}"


# --------------------------------------------------------------------------


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="compare and fail on a drift (the default)")
    mode.add_argument("--update", action="store_true", help="rewrite drifted numbers in the README")
    mode.add_argument("--list", action="store_true", help="print the runs and figures, run nothing")
    ap.add_argument("--all", action="store_true", help="also the slow runs")
    ap.add_argument("--runs", help="comma-separated run names (default: every run that is not slow)")
    ap.add_argument("--mspace", type=Path, default=Path(os.environ.get("MSPACE_EXE", ROOT / "build/bin/mspace")),
                    help="the mspace binary (default: $MSPACE_EXE or build/bin/mspace)")
    ap.add_argument("--readme", type=Path, default=ROOT / "README.md")
    ap.add_argument("--keep", type=Path,
                    help="write the runs' outputs here and keep them (a generated input found there is reused)")
    ap.add_argument("--reuse", action="store_true",
                    help="with --keep: read a run's summary.yaml already in that folder instead of running it again "
                         "(to re-check or --update after editing the README, not after a code change)")
    args = ap.parse_args()

    readme = args.readme.read_text(encoding="utf-8")
    quotes = find_quotes(readme)
    unknown = sorted({q.fig_id for q in quotes} - FIGURES.keys())
    if unknown:
        for i in unknown:
            print(f"readme_figures: README.md quotes fig:{i}, which {Path(__file__).name} does not define")
        return 2
    quoted_runs = {FIGURES[q.fig_id].run for q in quotes}

    if args.list:
        for name, run in RUNS.items():
            ids = sorted({q.fig_id for q in quotes if FIGURES[q.fig_id].run == name})
            print(f"{name}{' (slow)' if run.slow else ''}: mspace run {' '.join(run.args)}")
            print(f"    quoted: {', '.join(ids) or 'nothing (not run)'}")
        return 0

    if args.runs:
        selected = args.runs.split(",")
        for name in selected:
            if name not in RUNS:
                ap.error(f"unknown run {name}; known: {', '.join(RUNS)}")
            if name not in quoted_runs:
                ap.error(f"README.md quotes no figure of run {name}")
    else:
        selected = [n for n, r in RUNS.items() if args.all or not r.slow]
    selected = [n for n in selected if n in quoted_runs]  # a run nothing quotes is not run
    if args.reuse and not args.keep:
        ap.error("--reuse needs --keep DIR")
    if not args.mspace.is_file():
        print(f"readme_figures: no mspace binary at {args.mspace} (build first, or --mspace)")
        return 2

    work = args.keep or Path(tempfile.mkdtemp(prefix="readme_figures."))
    summaries: dict[str, dict | str] = {}
    try:
        for name in selected:
            kept = work / name / "summary.yaml"
            if args.reuse and kept.is_file():
                print(f"reuse {name}: {kept}")
                summaries[name] = yaml.safe_load(kept.read_text())
            else:
                summaries[name] = execute(name, RUNS[name], args.mspace.resolve(), work.resolve())
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)

    rows, drifts, checked, edits = [], 0, 0, []
    for q in quotes:
        fig = FIGURES[q.fig_id]
        if fig.run not in summaries:
            continue
        result = summaries[fig.run]
        if isinstance(result, str):
            rows.append((q, q.text, "—", "", "SKIP"))
            continue
        value = measure(fig, result)
        checked += 1
        # (1 + 1e-12): a value exactly half a unit off must not fail on the binary round-off of the subtraction.
        ok = abs(float(value) - float(q.value)) <= tolerance(fig, q) * (1 + 1e-12)
        drifts += not ok
        rounded = q.format(value)
        if rounded != q.text:
            edits.append((q, rounded))
        rows.append((q, q.text, f"{value:.6g}", describe_tolerance(fig, q), "OK" if ok else "DRIFT"))

    label = lambda q: f"{q.fig_id} (l.{q.line})"  # noqa: E731
    width = max([20] + [len(label(row[0])) for row in rows])
    print(f"\n{'figure (README line)':<{width}}  {'README':>10}  {'measured':>12}  {'tolerance':<13}  status")
    for q, said, got, tol, status in rows:
        print(f"{label(q):<{width}}  {said:>10}  {got:>12}  {tol:<13}  {status}")
    for name, result in summaries.items():
        if isinstance(result, str):
            print(f"SKIP {name}: {result}")
    print(f"{checked} figures checked, {drifts} drifted, "
          f"{sum(r[4] == 'SKIP' for r in rows)} skipped (timings are never checked)")

    if args.update:
        for q, text in sorted(edits, key=lambda e: e[0].start, reverse=True):
            readme = readme[:q.start] + text + readme[q.end:]
            print(f"{args.readme.name}:{q.line}: fig:{q.fig_id} {q.text} -> {text}")
        args.readme.write_text(readme, encoding="utf-8")
        print(f"{len(edits)} numbers rewritten in {args.readme}")
        return 0
    if drifts:
        print("A quoted figure is not what its run gives: if the change that moved it is right, run "
              "tools/readme_figures.py --update (--all for the ceiling rows) and review git diff README.md.")
    if checked == 0:
        return SKIPPED
    return 1 if drifts else 0


if __name__ == "__main__":
    sys.exit(main())
