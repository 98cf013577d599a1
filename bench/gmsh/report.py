#!/usr/bin/python3
"""Turns the logs of bench/gmsh/run.sh into bench/results/gmsh.md (stdout). Nothing is typed in
by hand: every figure comes from the logs in OUT."""
import glob, json, os, re, subprocess, sys, datetime

out = sys.argv[1]
def load(prefix, path):
    try:
        for line in open(path, errors="replace"):
            if line.startswith(prefix):
                return json.loads(line[len(prefix):])
    except OSError:
        pass
    return None

def timev(path):
    r = {}
    try:
        t = open(path).read()
    except OSError:
        return r
    m = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", t)
    if m:
        p = [float(x) for x in m.group(1).split(":")]
        r["wall"] = sum(x * 60 ** i for i, x in enumerate(reversed(p)))
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", t)
    if m:
        r["rss_mb"] = int(m.group(1)) / 1024
    m = re.search(r"rc=(\d+)", t)
    if m:
        r["rc"] = int(m.group(1))
    return r

def mf_stats(name):
    """The Gmsh-side fields of the table, from meshflow's own report.json (split's mesh stats)."""
    try:
        rep = json.load(open(os.path.join(out, name + ".out", "report.json")))
    except Exception:
        tail = open(os.path.join(out, name + ".log"), errors="replace").read().strip().splitlines()[-1:]
        return {"stage": "run", "error": (tail[0] if tail else "no report.json")[:200]}
    st = {s["name"]: s for s in rep["stages"]}
    last = rep["stages"][-1]["name"]
    if "split" not in st:
        return {"stage": "the workflow's end (%s; no high-order mesh yet)" % last, "error": "stages: " + ", ".join(s["name"] for s in rep["stages"])}
    sp = st["split"]["stats"]
    bt = sp["mesh"]["by_type"]
    fam = {"prism": "Prism", "tet": "Tetrahedron", "hex": "Hexahedron", "pyramid": "Pyramid"}
    counts = {}
    for k, v in bt.items():
        f = k.rstrip("0123456789")
        if f in fam:
            counts[fam[f]] = counts.get(fam[f], 0) + v
    return {"stage": "done", "counts": counts, "first_height": sp["split"]["first_layer_height"],
            "wall_triangles": sp["mesh"]["groups"].get("wall", "–"),
            "times_s": {s["name"]: round(s.get("seconds") or 0, 2) for s in rep["stages"]}}

rows = {}
for tf in sorted(glob.glob(os.path.join(out, "*.time"))):
    name = os.path.basename(tf)[:-5]
    geo, var = name.rsplit("_", 1)
    if var.startswith("meshflow"):
        st = mf_stats(name)
    else:
        st = load("STATS ", os.path.join(out, name + ".log")) or {}
    an = load("ANALYSE ", os.path.join(out, name + ".analyse"))
    try:
        q = json.load(open(os.path.join(out, name + ".quality.json")))
    except Exception:
        q = None
    rows.setdefault(geo, []).append((var, timev(tf), st, an, q))

ver = "?"
for g in rows.values():
    for r in g:
        ver = r[2].get("gmsh", ver)
print("## Gmsh side by side\n")
print("Produced by `bench/gmsh/run.sh` (figures from its logs via `bench/gmsh/report.py`) on %s, %d cores "
      "(shared with other jobs), Gmsh %s (Debian, Python API), meshflow commit %s. Each variant is one process "
      "under `/usr/bin/time -v` and `timeout`; wall time and peak RSS are those of the whole Gmsh process "
      "(import, surface mesh, layer, tets, order 4, optimisation, statistics, writing MSH 4.1). The meshes are "
      "judged afterwards, outside the timing, by Gmsh's `Plugin(AnalyseMeshQuality)` (`bench/gmsh/analyse.py`, "
      "`General.AbortOnError`=0, JacobianDeterminant, 3D elements) and by `meshflow quality --json` "
      "(Bézier bounds on det J, whole element). meshflow runs `meshflow run WORKFLOW` from an empty cache (all its stages, "
      "each in its own process; wall time and peak RSS of the largest process, as /usr/bin/time -v reports), alternating "
      "with the Gmsh variants; its mesh is judged by the same two checks.\n" % (
          datetime.date.today().isoformat(), os.cpu_count(), ver,
          subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()))
names = {"meshflow1": "meshflow (1st run)", "meshflow2": "meshflow (2nd run)", "meshflow3": "meshflow (3rd run)",
         "ho0": "order 4, no optimisation", "ho2": "order 4, HighOrderOptimize 2 (elastic + optimization)",
         "ho4": "order 4, HighOrderOptimize 4 (fast curving)"}
for geo, rs in rows.items():
    print("### %s\n" % {"wing": "Real wing (3d_bl_wing.stp)", "dlrf6": "DLR-F6 (dlr_f6.brep)"}.get(geo, geo))
    a0 = rs[0][2].get("args", {})
    if a0:
        print("Mesh parameters: unit scale %g, walls %s, wall size ≤ %g, curvature %d el./2π, far-field size %g, "
              "%d layers, ratio %g, first height %g (layer %s thick), classifySurfaces angle %g°.\n" % (
                  a0["scale"], a0["walls"], a0["wall_size"], a0["curv"], a0["far_size"], a0["layers"], a0["ratio"],
                  a0["first_height"], "%.4g" % rs[0][2].get("bl_thickness", float("nan")), a0["classify_angle"]))
    print("| variant | exit | wall time s | peak MB | wall triangles | prisms | tets | other 3D | first-layer height min/max | "
          "max aspect ratio (meshflow) | invalid by Gmsh (minJ/maxJ ≤ 0) | Gmsh min minJ/maxJ | invalid by meshflow | "
          "meshflow min scaled J | meshflow validity method |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    order = {"ho0": 0, "ho4": 1, "ho2": 2, "meshflow1": 3, "meshflow2": 4, "meshflow3": 5}
    for var, tv, st, an, q in sorted(rs, key=lambda r: order.get(r[0], 9)):
        c = st.get("counts", {})
        pr = sum(v for k, v in c.items() if k.startswith("Prism") or k in ("type91", "type106", "type6", "type18"))
        te = sum(v for k, v in c.items() if k.startswith("Tetra"))
        oth = sum(v for k, v in c.items() if k.startswith(("Hexa", "Pyramid")))
        fh = st.get("first_height")
        v = an["views"][0] if an and an.get("views") else None
        exitinfo = "ok" if st.get("stage") == "done" else "failed at %s: %s" % (st.get("stage", "?"), st.get("error", "timeout/killed (rc %s)" % tv.get("rc")))
        print("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            names.get(var, var), exitinfo.replace("|", "/"),
            "%.1f" % tv["wall"] if "wall" in tv else "–", "%.0f" % tv["rss_mb"] if "rss_mb" in tv else "–",
            st.get("wall_triangles", "–"), pr or "–", te or "–", oth,
            "%.3g / %.3g" % (fh["min"], fh["max"]) if fh else "–",
            "%.1f" % q["max_aspect_ratio"] if q else "–",
            "%d of %d" % (v["nonpositive"], v["n"]) if v else ("–" if not an else an.get("error", "no view")),
            "%.3g" % v["min"] if v and v["min"] is not None else "–",
            "%d (inconclusive %d)" % (q["invalid"], q.get("inconclusive", 0)) if q else "–",
            "%.3g" % q["min_scaled_jacobian"] if q else "–",
            q.get("validity_method", "") if q else "–"))
    print()
    for var, tv, st, an, q in rs:
        if st.get("times_s"):
            print("- %s: %s step times (s) %s" % (var, "meshflow" if var.startswith("meshflow") else "Gmsh", json.dumps(st["times_s"])))
        if st.get("footprint_loops") == [] and st.get("stage") != "done":
            print("  - the layer's top surface has no boundary loop (0 footprint loops): the extruded walls' mesh closes on "
                  "itself or the footprint on the symmetry plane was not found, so no hole was cut in the box and the tet "
                  "mesher saw the layer intersect the box face")
        if st.get("footprint_offplane_max") is not None:
            print("  - layer footprint off the box side by up to %.3g before projection; %s box nodes shared with the layer"
                  % (st["footprint_offplane_max"], st.get("box_nodes_shared_with_layer", "?")))
        errs = sorted(set(l for l in st.get("log_tail", []) if "rror" in l))
        if errs:
            print("  - Gmsh errors logged (non-fatal unless the run failed): " + "; ".join("`%s`" % e for e in errs))
        if an:
            al = [l for l in an.get("log", []) if "rror" in l or "minJ" in l or "Jacobian" in l]
            print("  - AnalyseMeshQuality (%.0f s): %s" % (an.get("time_s", 0), "; ".join("`%s`" % l for l in al[-6:])))
        if q is not None and an and an.get("views"):
            v = an["views"][0]
            gt = set(v.get("nonpositive_tags", [])); mt = set(q.get("invalid_elements", []))
            if "nonpositive_tags" not in v:
                print("  - (this AnalyseMeshQuality log predates recording the element tags; only counts compare)")
            elif gt or mt:
                print("  - invalid element tags: Gmsh %s, meshflow %s, in both %d" % (sorted(gt)[:12], sorted(mt)[:12], len(gt & mt)))
            print("  - checkers: Gmsh %d invalid (min %.4g), meshflow %d invalid (min scaled J %.4g, %d elements checked)"
                  % (v["nonpositive"], v["min"], q["invalid"], q["min_scaled_jacobian"], sum(q.get("elements", {}).values())))
    print()
    # meshflow against Gmsh's best attempt (fast curving, else no optimisation), the targets
    ok = lambda r: r[2].get("stage") == "done" and "wall" in r[1]
    mfr = [r for r in rs if r[0].startswith("meshflow") and ok(r)]
    gm = [r for r in rs if r[0] in ("ho4", "ho0") and ok(r)]
    if mfr and gm:
        best = sorted(gm, key=lambda r: {"ho4": 0, "ho0": 1}[r[0]])[0]
        walls = sorted(r[1]["wall"] for r in mfr)
        rss = max(r[1]["rss_mb"] for r in mfr)
        med = walls[len(walls) // 2]
        inv = [r[4]["invalid"] for r in mfr if r[4]]
        print("**meshflow / Gmsh (%s):** wall time %.2f× (median of %d meshflow runs, %.1f s, against %.1f s; target ≤ 0.5×: %s), "
              "peak memory %.2f× (%.0f MB against %.0f MB; target ≤ 1×: %s); invalid elements by meshflow's check: meshflow %s, Gmsh %s "
              "(target 0: %s).\n" % (
                  names[best[0]], med / best[1]["wall"], len(walls), med, best[1]["wall"], "met" if med <= 0.5 * best[1]["wall"] else "missed",
                  rss / best[1]["rss_mb"], rss, best[1]["rss_mb"], "met" if rss <= best[1]["rss_mb"] else "missed",
                  "/".join(str(i) for i in inv) or "–", best[4]["invalid"] if best[4] else "–",
                  "met" if inv and max(inv) == 0 else "missed"))
        mid = sorted(mfr, key=lambda r: r[1]["wall"])[len(mfr) // 2]
        top = sorted(mid[2].get("times_s", {}).items(), key=lambda kv: -kv[1])[:4]
        print("Where meshflow's time goes (median run, seconds per stage): %s; the rest is process start-up, cache "
              "writes and the quality statistics every meshing stage computes for its summary.\n"
              % ", ".join("%s %.1f" % kv for kv in top))
        if any(r[3] and r[3].get("views") and r[3]["views"][0]["nonpositive"] for r in mfr):
            print("Gmsh's AnalyseMeshQuality flags meshflow's order-4 pyramids (its high-order pyramid analysis; Gmsh's own "
                  "`getJacobians` finds det J > 0 at every sample of them, and meshflow's Bernstein bounds of det J in collapsed "
                  "coordinates prove them valid over the whole element, see README) — the other flagged counts above are "
                  "those pyramids.\n")
    elif any(r[0].startswith("meshflow") for r in rs):
        r = [r for r in rs if r[0].startswith("meshflow")][0]
        print("**meshflow:** no high-order mesh to compare: it stops at %s (%s).\n" % (r[2].get("stage"), r[2].get("error", "")))

print("""### How the Gmsh mesh is made, and what failed on the way

Commands: `bench/gmsh/run.sh build-gmshbench/meshflow /tmp/meshflow-gmshbench` runs, per geometry and per
variant, `/usr/bin/time -v timeout 300 /usr/bin/python3 bench/gmsh/wing_bl.py CAD OUT.msh ARGS --layers 10
--ratio 1.5 --order 4 --hoopt {0,4,2}` (ARGS as in the parameter lines above), then
`bench/gmsh/analyse.py OUT.msh` and `meshflow quality OUT.msh --json`.

Route that works in Gmsh 4.8 (`wing_bl.py`):
1. OCC import (wing: `Geometry.OCCFixDegenerated/OCCSewFaces/OCCMakeSolids` = 1, which sews the 9 faces; DLR-F6: no
   healing — with it OCC returned 130 faces and no volume instead of 129 faces and 1 volume), scale mm→m, remove
   the far-field box faces, 2D mesh of the walls (Frontal-Delaunay, size from curvature, capped).
2. The wall mesh is written and reopened as a discrete model and `classifySurfaces` rebuilds its topology.
3. `geo.extrudeBoundaryLayer(walls, [1]*10, cumulative heights h1(1.5^k-1)/0.5, recombine=True)` on the
   mesh-normal side that points into the fluid (sign from the signed volume of the wall mesh).
4. The layer is meshed and frozen (written and reopened), its top footprint loop is moved onto the box side
   (tunnel floor / symmetry plane; the mesh normals there are not parallel to it — the offset is printed above),
   the box with a polygonal hole through those exact nodes is meshed in a second OCC model and copied back as
   discrete surfaces sharing the footprint nodes; `geo.addSurfaceLoop/addVolume` + Delaunay tets.
5. `setOrder(4)`; `optimize("HighOrderElastic")` + `optimize("HighOrder")` for HighOrderOptimize 2,
   `optimize("HighOrderFastCurving")` for 4 (the option itself is only applied by `generate()`, not by
   the API's `setOrder()`).

Consequence to keep in mind when comparing: the walls are discrete (a triangulation) when the order is raised,
so Gmsh places the high-order wall nodes on the flat triangles, not on the CAD — the Gmsh mesh is *not*
curved to the geometry; only the optimisation moves interior nodes. The layer's root nodes below the top are
not moved onto the floor/symmetry plane either (meshflow's bbox of the mesh shows them up to that offset
outside the box).

Failures met (Gmsh messages verbatim):
- `extrudeBoundaryLayer` on the reopened OCC-meshed walls without `classifySurfaces`: nothing is extruded for
  the wall curves; meshing then stops with `Could not find extruded node (...) in surface 22`; passing the curves
  explicitly gives `Cannot extrude curve with no begin/end points`; with `createGeometry()` the walls are
  remeshed by `generate(3)` and the same `Could not find extruded node` follows.
- Flipping faces by the OCC boundary-curve signs (`mesh.setReverse`) made the mesh orientation *inconsistent*:
  Gmsh already orients the wall triangles consistently (0 interior mesh edges used twice in one direction).
- Closing the outer volume in the built-in kernel from the layer's top curves: they have no end points,
  `geo.addCurveLoops` returns a tag that `addPlaneSurface` then reports as `Unknown curve loop`, or meshing
  gives `Unable to recover the edge ... on curve 68`; replaced by the second-model box described above.
- Remeshing after moving footprint nodes re-extrudes the layer: `Could not find extruded vertex (...)`; hence
  the freeze (write/reopen) before the outer volume.
- DLR-F6 with the symmetry plane counted as a wall (automatic wall detection misses it: the CAD's bounding box
  reaches y = +3.9e-3 mm, beyond the plane): `PLC Error: A segment and a facet intersect at point`; the walls
  are therefore given explicitly (faces 1-123).
- `FaceClosureFull not implemented for prisms of order 4` is logged by `getElementProperties` and by
  AnalyseMeshQuality for P4 prisms (the plugin still reports a minJ/maxJ for every element).
- The `BoundaryLayer` mesh field was not tried for 3D: in Gmsh 4.8 it only acts on 2D meshes.
""")
