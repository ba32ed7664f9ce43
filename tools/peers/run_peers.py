#!/usr/bin/env python3
"""Peer comparison: MRPT's icp-slam against mspace on the same input, all
scored by `mspace eval` on the same reference and relations (docs/peers.md).

    tools/peers/run_peers.py --build build --out out/peers \
        --inputs intel,ring:1,ladder:1 --systems icp,ekf,smoother

Inputs: `intel` (the Intel Research Lab's 910 scans with raw odometry, from
$MSPACE_DATA/intel_lab; reference = GMapping's poses, relations = Kuemmerle's),
`PLAN:SEED[:PEOPLE]` (an office building written by mspace-sim-building with
world seed = seed = SEED and PEOPLE people walking, by default the plan's: 2,
none in symmetric; reference = its ground truth, relations = its relations)
and `log:FILE[:RELATIONS]` (any CARMEN log with FLASER lines, e.g. another
building's; mspace runs config/intel_walls.yaml on it, scored by RELATIONS).
Each input becomes one CARMEN log; MRPT gets it through carmen2rawlog, mspace
reads the same log (Intel: the same scans and odometry from the table both are
written from).

Systems: odometry (the input's wheel odometry alone, scored for scale), icp
(MRPT icp-slam, tools/peers/icp-slam.ini), ekf and smoother (`mspace run` with
config/intel_walls.yaml or config/sim_building.yaml and --estimator), and
smoother+lc (the smoother with association.loop_closing=true).

(MRPT's rbpf-slam is not run: it reads action/sensory-frame rawlogs, and
carmen2rawlog 2.5.8 writes observation-only ones, on which it crashes at the
first entry; rawlog-edit 2.5.8 has no conversion. docs/peers.md.)

MRPT's icp-slam writes one pose per rawlog entry and no time stamps;
carmen2rawlog turns each laser line into an odometry and a laser entry, in the log's order.
`rawlog-edit --list-timestamps` lists the entries' classes, so the pose after
the k-th laser entry is given the time of the k-th laser line of the CARMEN
log (see mrpt_path_to_tum).

Writes OUT/<input>/result_<system>.json, OUT/results.json (all of them) and
OUT/results.md (the table of docs/peers.md). Only the standard library; MRPT's tools must be on PATH.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.dirname(os.path.dirname(HERE))


def log(msg):
    print(msg, flush=True)


def run(cmd, out_file=None, env=None, cwd=None):
    """Runs cmd (a list); returns (wall seconds, load average at the start).
    Output goes to out_file; a failure raises with the tail of it."""
    load = os.getloadavg()[0]
    start = time.monotonic()
    with open(out_file or os.devnull, "w") as out:
        rc = subprocess.call(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                             env=env, cwd=cwd)
    seconds = time.monotonic() - start
    if rc != 0:
        tail = ""
        if out_file:
            with open(out_file) as f:
                tail = "".join(f.readlines()[-15:])
        raise RuntimeError("%s failed (exit %d)\n%s" % (" ".join(cmd), rc, tail))
    return seconds, load


# ---- inputs -----------------------------------------------------------------

def intel_input(data_dir, out):
    """The Intel 910 scans as a CARMEN log with raw odometry, and the GMapping
    reference as `t x y theta`. Beam i of the table is at -90 + i deg, as
    mspace reads it; for MRPT the aperture is 179 deg and each laser pose is
    turned by -0.5 deg (flaser_line_for_mrpt)."""
    table = os.path.join(data_dir, "intel_lab", "intel_910_scans.txt")
    relations = os.path.join(data_dir, "intel_lab", "intel.relations")
    if not os.path.exists(table):
        raise FileNotFoundError("%s is absent (set MSPACE_DATA)" % table)
    log_file = os.path.join(out, "intel.clf")
    reference = os.path.join(out, "intel_gmapping.txt")
    odometry = os.path.join(out, "intel_odometry.txt")
    with open(table) as src, open(log_file, "w") as clf, open(reference, "w") as ref, open(odometry, "w") as odo:
        clf.write("PARAM robot_front_laser_max 81.0\n")
        clf.write("PARAM laser_front_laser_resolution %.12f\n" % flaser_resolution_deg(180, 180.0))
        ref.write("# t x y theta: GMapping's corrected poses (intel_910_scans.txt)\n")
        for line in src:
            f = line.split()
            if not f or f[0].startswith("#"):
                continue
            t, (ox, oy, oth) = f[0], map(float, f[1:4])
            line = "FLASER 180 %s %.6f %.6f %.9f %.6f %.6f %.9f %s peers %s" % (
                " ".join(f[7:187]), ox, oy, oth, ox, oy, oth, t, t)
            clf.write(flaser_line_for_mrpt(line.split(), 180.0) + "\n")
            ref.write("%s %s %s %s\n" % (t, f[4], f[5], f[6]))
            odo.write("%s %s %s %s\n" % (t, f[1], f[2], f[3]))
    return {"name": "intel", "clf": log_file, "reference": reference, "relations": relations, "odometry": odometry,
            "config": os.path.join(SOURCE, "config", "intel_walls.yaml"),
            "env": {"MSPACE_DATA": data_dir}, "sets": []}


def flaser_line_for_mrpt(fields, fov_deg):
    """A FLASER line (fields) as MRPT must read it to see the beams where
    mspace's carmen_log puts them (centred: with n beams over fov, an even n
    at -fov/2 + i*fov/n, an odd n at -fov/2 + i*fov/(n-1)). MRPT spreads n
    beams evenly over an aperture centred on the laser's heading, so an even
    n needs the aperture (n-1)*fov/n and the laser turned by -fov/(2n)."""
    n = int(fields[1])
    offset = math.radians(fov_deg) / (2 * n) if n % 2 == 0 else 0.0
    laser_theta = 2 + n + 2
    fields = list(fields)
    fields[laser_theta] = "%.9f" % (float(fields[laser_theta]) - offset)
    return " ".join(fields)


def flaser_resolution_deg(n, fov_deg):
    """The PARAM laser_front_laser_resolution that gives MRPT the aperture
    flaser_line_for_mrpt assumes (MRPT: aperture = resolution * n)."""
    aperture = (n - 1) * fov_deg / n if n % 2 == 0 else fov_deg
    return aperture / n


def log_input(path, relations, fov_deg, out):
    """Any CARMEN log with FLASER lines (e.g. another building's): mspace reads
    it with config/intel_walls.yaml (no ground truth), MRPT a copy whose
    FLASER lines are adjusted as flaser_line_for_mrpt says. Scored by the
    relations file when one is given."""
    name = os.path.splitext(os.path.basename(path))[0]
    work = os.path.join(out, "log_" + name)
    os.makedirs(work, exist_ok=True)
    mrpt_log = os.path.join(work, name + ".mrpt.clf")
    resolution = None
    with open(path) as src, open(mrpt_log, "w") as dst:
        for line in src:
            f = line.split()
            if not f or (f[0] == "PARAM" and len(f) > 1 and f[1] == "laser_front_laser_resolution"):
                continue
            if f[0] == "FLASER":
                if resolution is None:
                    resolution = flaser_resolution_deg(int(f[1]), fov_deg)
                    dst.write("PARAM laser_front_laser_resolution %.12f\n" % resolution)
                line = flaser_line_for_mrpt(f, fov_deg) + "\n"
            dst.write(line)
    sets = ["source.file=" + os.path.abspath(path), "source.ground_truth=none", "source.initial_pose=odometry",
            "source.flaser_fov_deg=%g" % fov_deg, "evaluation.relations=" + (os.path.abspath(relations) if relations else "")]
    return {"name": name, "clf": mrpt_log, "reference": None, "relations": relations, "odometry": None,
            "config": os.path.join(SOURCE, "config", "intel_walls.yaml"), "env": {}, "sets": sets, "work": work}


def building_input(build, plan, seed, people, out):
    """people: None for the simulator's default (two people walking), else their number."""
    suffix = "" if people is None else "_people%d" % people
    folder = os.path.join(out, "%s_%d%s" % (plan, seed, suffix))
    if not os.path.exists(os.path.join(folder, "building.clf")):
        run([os.path.join(build, "bin", "mspace-sim-building"), "--out", folder, "--plan", plan,
             "--world-seed", str(seed), "--seed", str(seed), "--laser", "sick181"] +
            ([] if people is None else ["--people", str(people)]),
            os.path.join(out, "sim_%s_%d%s.log" % (plan, seed, suffix)))
    return {"name": "%s %d%s" % (plan, seed, "" if people is None else ", %d people" % people),
            "clf": os.path.join(folder, "building.clf"),
            "reference": os.path.join(folder, "ground_truth.tum"),
            "relations": os.path.join(folder, "building.relations"),
            "odometry": os.path.join(folder, "odometry.tum"),
            "config": os.path.join(SOURCE, "config", "sim_building.yaml"),
            "env": {"MSPACE_SIM_BUILDING": folder}, "sets": []}


def laser_line_times(clf):
    """Time stamps of the laser lines of a CARMEN log, in order (the field
    before the host name, i.e. the third from the end)."""
    times = []
    with open(clf) as f:
        for line in f:
            if line.startswith(("FLASER", "ROBOTLASER1", "RLASER")):
                times.append(line.split()[-3])
    return times


# ---- MRPT -------------------------------------------------------------------

def mrpt_path_to_tum(path_file, entries_file, times, tum):
    """icp-slam's `step x y phi` lines -> `t x y theta`: the pose
    after the k-th laser entry gets the k-th laser line's time."""
    classes = []
    with open(entries_file) as f:
        for line in f:
            f3 = line.split()
            if len(f3) >= 3:
                classes.append(f3[2])
    laser_steps = [i for i, c in enumerate(classes) if c.endswith("CObservation2DRangeScan")]
    if len(laser_steps) != len(times):
        raise RuntimeError("%s lists %d laser entries, the log has %d laser lines" %
                           (entries_file, len(laser_steps), len(times)))
    poses = {}
    with open(path_file) as f:
        for line in f:
            v = line.split()
            if len(v) >= 4:
                poses[int(v[0])] = v[1:4]
    with open(tum, "w") as out:
        out.write("# t x y theta (from %s)\n" % path_file)
        for k, step in enumerate(laser_steps):
            if step in poses:
                out.write("%s %s %s %s\n" % (times[k], *poses[step]))


def write_ini(template, out_dir, ini, overrides):
    """A copy of template with logOutput_dir = out_dir and each
    SECTION.KEY=VALUE of overrides replacing that key in that section."""
    wanted = {}
    for o in overrides:
        key, _, value = o.partition("=")
        section, _, name = key.rpartition(".")
        wanted[(section, name)] = value
    with open(template) as f:
        text = f.read()
    lines, section, done = [], "", set()
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("["):
            section = stripped.strip("[]")
        name = stripped.partition("=")[0].strip()
        if name == "logOutput_dir":
            line = "logOutput_dir = " + out_dir
        elif (section, name) in wanted and "=" in stripped and not stripped.startswith("#"):
            line = "%s = %s" % (name, wanted[(section, name)])
            done.add((section, name))
        lines.append(line)
    missing = set(wanted) - done
    if missing:
        raise RuntimeError("%s has no key %s" % (template, ", ".join("%s.%s" % m for m in sorted(missing))))
    with open(ini, "w") as f:
        f.write("\n".join(lines) + "\n")


def run_mrpt(app, inp, work, rawlog, entries, overrides, tag):
    out_dir = os.path.join(work, app + tag)
    os.makedirs(out_dir, exist_ok=True)
    ini = os.path.join(out_dir, app + ".ini")
    write_ini(os.path.join(HERE, app + ".ini"), os.path.join(out_dir, "log"), ini, overrides)
    seconds, load = run([app, ini, rawlog], os.path.join(out_dir, app + ".out"), cwd=out_dir)
    path_name = "log_estimated_path.txt"
    tum = os.path.join(out_dir, "trajectory.txt")
    mrpt_path_to_tum(os.path.join(out_dir, "log", path_name), entries, laser_line_times(inp["clf"]), tum)
    return tum, seconds, load


# ---- mspace -----------------------------------------------------------------

def run_mspace(build, system, inp, work, extra_sets):
    """system: an estimator name, with "+lc" for association.loop_closing on."""
    estimator, _, loop = system.partition("+")
    out_dir = os.path.join(work, "mspace_" + system.replace("+", "_"))
    env = dict(os.environ, **inp["env"])
    cmd = [os.path.join(build, "bin", "mspace"), "run", inp["config"], "--out", out_dir, "--estimator", estimator,
           "--quiet"]
    if loop == "lc":
        cmd += ["--set", "association.loop_closing=true"]
    for s in inp["sets"] + extra_sets:
        cmd += ["--set", s]
    seconds, load = run(cmd, out_dir + ".out", env=env)
    return os.path.join(out_dir, "trajectory.tum"), seconds, load


def evaluate(build, trajectory, inp, yaml_file):
    cmd = [os.path.join(build, "bin", "mspace"), "eval", trajectory, "--yaml", yaml_file]
    if inp["reference"]:
        cmd += ["--reference", inp["reference"]]
    if inp["relations"]:
        cmd += ["--relations", inp["relations"]]
    if len(cmd) == 5:
        return {}
    run(cmd, yaml_file + ".out")
    figures = {}
    with open(yaml_file) as f:
        for line in f:
            key, _, value = line.partition(":")
            value = value.strip()
            try:
                figures[key] = float(value)
            except ValueError:
                figures[key] = value.strip('"')
    return figures


# ---- table ------------------------------------------------------------------

def cell(fig, prefix):
    if fig.get(prefix + "_matched", 0) == 0:
        return "–"
    return "%.3f ± %.3f m, %.2f°" % (fig[prefix + "_translation_mean_m"], fig[prefix + "_translation_std_m"],
                                     fig[prefix + "_rotation_mean_deg"])


def markdown(records):
    rows = ["| input | system | ATE RMSE | relations: all | short (< 60 s) | long (≥ 60 s) (n) | wall time | load (1 min) |",
            "|---|---|---|---|---|---|---|---|"]
    for r in records:
        if "error" in r:
            rows.append("| %s | %s | failed: %s | | | | | |" % (r["input"], r["system"], r["error"].splitlines()[0]))
            continue
        f = r["figures"]
        rows.append("| %s | %s | %s | %s | %s | %s (%d) | %.0f s | %.0f |" % (
            r["input"], r["system"], "%.3f m" % f["ate_rmse_m"] if "ate_rmse_m" in f else "–",
            cell(f, "relations_all"), cell(f, "relations_short"), cell(f, "relations_long"),
            f.get("relations_long_matched", 0), r["seconds"], r["load"]))
    return "\n".join(rows) + "\n"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--build", default=os.path.join(SOURCE, "build"))
    p.add_argument("--out", default="out/peers")
    p.add_argument("--data", default=os.environ.get("MSPACE_DATA", os.path.join(SOURCE, "..", "shared", "datasets")))
    p.add_argument("--inputs", default="intel,ring:1,ladder:1,l_ring:1,grid:1,long_loop:1,symmetric:1",
                   help="comma-separated: intel, PLAN:SEED[:PEOPLE] (a generated building; PEOPLE walking, default the plan's), log:FILE[:RELATIONS] (any "
                        "CARMEN log with FLASER lines)")
    p.add_argument("--flaser-fov-deg", type=float, default=180.0,
                   help="field of view of a log: input's FLASER scans (as carmen_log's flaser_fov_deg)")
    p.add_argument("--systems", default="odometry,icp,ekf,smoother,smoother+lc",
                   help="comma-separated: odometry, icp, ekf, smoother, smoother+lc")
    p.add_argument("--reuse", action="store_true",
                   help="do not run a system again whose trajectory (and timing) OUT/results.json already has; "
                        "only score it again")
    p.add_argument("--mrpt-set", action="append", default=[], dest="mrpt_sets",
                   help="SECTION.KEY=VALUE replacing a key of the MRPT .ini (repeatable), e.g. ICP.thresholdDist=1.0")
    p.add_argument("--tag", default="", help="appended to the MRPT system's name and folder (for variants)")
    p.add_argument("--set", action="append", default=[], dest="sets",
                   help="KEY=VALUE passed to every mspace run (repeatable)")
    a = p.parse_args()
    build, out = os.path.abspath(a.build), os.path.abspath(a.out)
    os.makedirs(out, exist_ok=True)
    for tool in ("carmen2rawlog", "rawlog-edit"):
        if shutil.which(tool) is None:
            sys.exit("%s is not on PATH (Debian: apt-get install mrpt-apps)" % tool)
    for spec in filter(None, a.inputs.split(",")):  # --inputs "": only the table again
        if spec == "intel":
            work = os.path.join(out, "intel")
            os.makedirs(work, exist_ok=True)
            try:
                inp = intel_input(os.path.abspath(a.data), work)
            except FileNotFoundError as e:
                log("skipping intel: %s" % e)
                continue
        elif spec.startswith("log:"):
            parts = spec.split(":")
            inp = log_input(parts[1], parts[2] if len(parts) > 2 else None, a.flaser_fov_deg, out)
            work = inp["work"]
        else:
            parts = spec.split(":")  # PLAN:SEED[:PEOPLE]
            inp = building_input(build, parts[0], int(parts[1]), int(parts[2]) if len(parts) > 2 else None, out)
            work = os.path.dirname(inp["clf"])
        rawlog = os.path.join(work, "input.rawlog")
        entries = os.path.join(work, "input.entries.txt")
        if not (a.reuse and os.path.exists(entries)):
            run(["carmen2rawlog", "-q", "-w", "-i", inp["clf"], "-o", rawlog], rawlog + ".out")
            run(["rawlog-edit", "--list-timestamps", "-i", rawlog, "--text-file-output", entries], entries + ".out")
        for system in a.systems.split(","):
            log("%s: %s ..." % (inp["name"], system))
            if system not in ("odometry", "icp", "ekf", "smoother", "smoother+lc"):
                sys.exit("unknown system '%s' (odometry, icp, ekf, smoother, smoother+lc)" % system)
            if system == "odometry" and not inp["odometry"]:
                continue
            mrpt = system == "icp"
            name = {"icp": "MRPT icp-slam" + a.tag, "odometry": "wheel odometry alone"}.get(system, "mspace " + system)
            # One file per input and system, so that runs of several inputs may go at once.
            record_file = os.path.join(work, "result_%s.json" % name.replace(" ", "_").replace("+", "_"))
            earlier = json.load(open(record_file)) if os.path.exists(record_file) else None
            record = {"input": inp["name"], "system": name}
            try:
                if a.reuse and earlier and "seconds" in earlier and os.path.exists(earlier["trajectory"]):
                    trajectory, seconds, load = earlier["trajectory"], earlier["seconds"], earlier["load"]
                elif system == "odometry":  # the input's own odometry, for scale
                    trajectory, seconds, load = inp["odometry"], 0.0, os.getloadavg()[0]
                elif mrpt:
                    trajectory, seconds, load = run_mrpt("icp-slam", inp, work, rawlog, entries, a.mrpt_sets, a.tag)
                else:
                    trajectory, seconds, load = run_mspace(build, system, inp, work, a.sets)
                record.update(seconds=seconds, load=load, trajectory=trajectory,
                              figures=evaluate(build, trajectory, inp, trajectory + ".eval.yaml"))
                if mrpt:
                    record["mrpt_sets"] = a.mrpt_sets
                f = record["figures"]
                log("  ATE %.3f m, relations all %.3f m, long %s, %.1f s (load %.1f)" % (
                    f.get("ate_rmse_m", float("nan")), f.get("relations_all_translation_mean_m", float("nan")),
                    cell(f, "relations_long"), seconds, load))
            except Exception as e:  # one failing run must not lose the others
                record["error"] = str(e)
                log("  failed: %s" % e)
            with open(record_file, "w") as f:
                json.dump(record, f, indent=1)
    records = []
    for folder in sorted(os.listdir(out)):
        path = os.path.join(out, folder)
        if os.path.isdir(path):
            records += [json.load(open(os.path.join(path, n))) for n in sorted(os.listdir(path))
                        if n.startswith("result_") and n.endswith(".json")]
    with open(os.path.join(out, "results.json"), "w") as f:
        json.dump(records, f, indent=1)
    with open(os.path.join(out, "results.md"), "w") as f:
        f.write(markdown(records))
    log("table: %s" % os.path.join(out, "results.md"))


if __name__ == "__main__":
    main()
