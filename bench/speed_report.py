#!/usr/bin/python3
"""bench/speed.sh's logs -> bench/results/speed.md: issue 24's table, each figure beside its goal.
Usage: speed_report.py OUT_DIR "ROWS RUN" COMMIT"""
import datetime
import json
import os
import re
import sys

out, only, commit = sys.argv[1], sys.argv[2].split(), sys.argv[3]


def read(name, ext):
    p = os.path.join(out, f"{name}.{ext}")
    return open(p).read() if os.path.exists(p) else None


def timed(name):
    """(wall s, peak MB, exit code, load) of a /usr/bin/time -f '%e %M' run, or None."""
    t = read(name, "time")
    if t is None:
        return None
    rc = int(re.search(r"rc=(\d+)", t).group(1))
    m = re.search(r"^([\d.]+) (\d+)$", t, re.M)
    if not m:  # killed before time could write its line
        return None
    load = (read(name, "load") or "load ?").split()[1]
    return float(m.group(1)), int(m.group(2)) / 1024, rc, load


def report(name):
    r = read(name, "report.json")
    return json.loads(r) if r else None


def stage(rep, name):
    for s in (rep or {}).get("stages", []):
        if s.get("name") == name:
            return s
    return None


def untangle(rep):
    s = stage(rep, "optimise")
    if not s:
        return None
    return s.get("stats", {}).get("optimise", {}).get("untangle")


def verdict(rep):
    if rep is None:
        return "no report"
    return "valid" if rep.get("ok") and not rep.get("invalid") else "NOT valid / failed"


rows = []  # (figure, measured, goal, met, how)
notes = []

if "wing" in only:
    g = [timed(f"gmsh_wing{k}") for k in (1, 2)]
    m = [timed(f"mf_wing{k}") for k in (1, 2)]
    gok = [x for x in g if x and x[2] == 0]
    mok = [x for x in m if x and x[2] == 0]
    if gok and mok:
        gb, mb = min(x[0] for x in gok), min(x[0] for x in mok)
        ratio = mb / gb
        rep = report("mf_wing1")
        rows.append(("the paper's wing, order 4, cold: meshflow / Gmsh (fast curving)",
                     f"**{mb:.1f} s / {gb:.1f} s = {ratio:.2f}x** (meshflow {verdict(rep)}; peak {max(x[1] for x in mok):.0f} "
                     f"vs {max(x[1] for x in gok):.0f} MB)", "<= 0.5x", "met" if ratio <= 0.5 else "not met",
                     "best of 2 each, alternating"))
        stages = sorted(((s["seconds"], s["name"]) for s in (rep or {}).get("stages", [])), reverse=True)[:4]
        notes.append("wing, meshflow's longest stages (first run): " +
                     ", ".join(f"{n} {t:.1f} s" for t, n in stages))
        notes.append("wing runs (wall s, load): Gmsh " + ", ".join(f"{x[0]:.1f} ({x[3]})" for x in g if x) +
                     "; meshflow " + ", ".join(f"{x[0]:.1f} ({x[3]})" for x in m if x))
    else:
        rows.append(("the paper's wing: meshflow / Gmsh", "a run failed (see the logs)", "<= 0.5x", "not met", ""))

for key, name, title, goal in (("dlr", "dlr", "DLR-F6 (`workflows/wing_body.yaml`) cold", 60),
                               ("rotor", "rotor67", "Rotor 67 (`workflows/rotor67.yaml`) cold", 180)):
    if key not in only:
        continue
    t, rep = timed(name), report(name)
    u = untangle(rep)
    if not t:
        rows.append((title, "no result", f"<= {goal} s", "not met", ""))
        continue
    us = f"; untangling {u['seconds']:.0f} s for {u['invalid']['before']} elements ({u['work']['jacobian_samples'] / 1e6:.0f} M samples)" if u else ""
    rows.append((title, f"**{t[0]:.0f} s**{us} ({verdict(rep)}, load {t[3]})", f"<= {goal} s",
                 "met" if t[2] == 0 and t[0] <= goal else "not met", "one run"))
    stages = sorted(((s["seconds"], s["name"]) for s in (rep or {}).get("stages", [])), reverse=True)[:4]
    notes.append(f"{title}, longest stages: " + ", ".join(f"{n} {s:.1f} s" for s, n in stages) +
                 f"; the whole run's peak RSS (GNU time: the largest stage process or the out/ writers) {t[1]:.0f} MB")
    if key == "rotor":
        sp = stage(rep, "split")
        mb = sp.get("peak_rss_mb") if sp else None
        nodes = None
        try:
            nodes = sp["stats"]["mesh"]["nodes"]
        except (KeyError, TypeError):
            pass
        per = f", {mb * 1048576 / nodes:.0f} bytes per order-4 node ({nodes:,} nodes)" if mb and nodes else ""
        rows.append(("Rotor 67 split peak memory", f"**{mb:.0f} MB**{per}" if mb else "no result", "<= 1536 MB",
                     "met" if mb and mb <= 1536 else "not met", "peak RSS of the split process"))

if "split" in only:
    log = read("split", "log") or ""
    m = re.search(r"\| ratio split-only / cold \| ([\d.]+) % \| ([\d.]+) % \|", log)
    cold = re.search(r"\| cold: .*?\| ([\d.]+) \| ([\d.]+) \|", log)
    if m:
        rows.append(("split-only change (`--set split.layers=12`) / cold, demo",
                     f"**{m.group(1)} %** wall, {m.group(2)} % CPU (cold {cold.group(1)} s)" if cold else f"{m.group(1)} %",
                     "<= 5 %", "met" if float(m.group(1)) <= 5 else "not met", "bench/split-change.sh"))
    else:
        rows.append(("split-only change / cold, demo", "no result (see split.log)", "<= 5 %", "not met", ""))

if "cylinder" in only:
    t, rep = timed("cylinder"), report("cylinder")
    u = untangle(rep)
    if t:
        if u and u["invalid"]["before"] > 0:
            what = (f"untangling {u['seconds']:.1f} s: {u['invalid']['before']} invalid -> {u['invalid']['after']}, "
                    f"{u['repaired']} repaired")
        else:
            what = "curving leaves no element invalid: nothing to untangle"
        notes.append("cylinder: a stage whose untangling repairs nothing stops after its no-progress budget "
                     "(optimise.untangle_budget, 40 M Jacobian samples, deterministic); tests/optimise/untangle_test.cpp "
                     "asserts it (\"the no-progress budget and the time limit stop the untangling\")")
        fast = not u or u["invalid"]["before"] == 0 or u["repaired"] > 0 or u["seconds"] < 60
        rows.append(("a cylinder in a box (`workflows/cylinder_in_box.yaml`): untangling that repairs nothing",
                     f"**{what}**; whole run {t[0]:.0f} s ({verdict(rep)})", "fail fast", "met" if fast else "not met",
                     "one run"))

print("## Speed: issue 24's table, measured in one run")
print()
print(f"`bench/speed.sh` (part of `make bench`) on {datetime.date.today()}, commit {commit}, "
      f"{os.cpu_count()} cores; logs in {out}. Each row is measured by the command named in the script's header; "
      "the load average before each run is given: on a shared machine wall time follows it.")
print()
print("| figure | measured | goal | | how |")
print("|---|---|---|---|---|")
for r in rows:
    print("| " + " | ".join(r) + " |")
missing = [k for k in ("wing", "dlr", "rotor", "split", "cylinder") if k not in only]
if missing:
    print()
    print("Not run this time: " + ", ".join(missing) + " (`SPEED_ONLY`).")
print()
for n in notes:
    print(f"- {n}")
