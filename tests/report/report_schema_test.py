#!/usr/bin/python3
"""report.json against schemas/report.schema.json, on the reports of real runs.

Usage: report_schema_test.py PROJECT_ROOT MESHFLOW_EXE [--keep DIR]

The runs, small enough for `make test` and covering the 14 stage kinds and the run's outcomes:
  demo       workflows/naca_wingtip.yaml, shrunk (far field 3 chords, coarser walls, order 2,
             3 layers), uploading to a remote cache (tests/remote/tiny_server.py)
  remote     the same on an empty local cache: every stage served by the remote cache
  rerun      the demo again on its cache: every stage cached
  quarantine one object of the demo's cache corrupted: quarantined, its stage recomputed
  invalid    the demo without untangling: the delivered mesh has inverted elements, exit 3
  accepted   the same with --allow-invalid: exit 0, invalid_accepted
  failed     tet with an element budget of 10: tet fails (exit 1), the stages after it skipped
  matrix     the demo with a matrix of two split variants: a report per variant
  step       the demo's healed shape written as STEP, imported by a `step` stage and healed
  wing_body  the parametric wing-body's geometry, healed
  translation the parametric wing with periodic box sides: periodic_match finds a translation
  blade      a synthetic blade row (scripts/synthetic-blade.py): blade_sector to periodic_match
Every report must validate against the schema (additionalProperties false where the fields are
known: a field the schema does not document fails), and every field the schema documents must
appear in at least one report (so the schema does not keep fields that are gone), but for the
few listed in NOT_EXERCISED with the condition that writes them, which no small run meets.
"""
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import jsonschema

ROOT, EXE = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
KEEP = sys.argv[4] if len(sys.argv) > 4 and sys.argv[3] == "--keep" else None
SMALL = ["--set", "geometry.farfield_chords=3", "--set", "balance.min_size=0.015", "--set", "balance.max_size=0.15",
         "--set", "curve.order=2", "-j", "2", "--threads", "2"]
DEMO = os.path.join(ROOT, "workflows", "naca_wingtip.yaml")

# Documented fields no run of this test writes: each written only in a condition no small run
# meets, named here (a key names the field and everything under it).
NOT_EXERCISED = {
    "error": "writing the outputs failed after the stages ran (disk full, out/ removed meanwhile)",
    "#contract.reference_volume_unreliable": "OpenCASCADE's two volume integrations of the CAD disagree",
    "#problem_place.why": "a degenerate element (tests/contract makes them)",
    "#problem_place.ratio": "a degenerate element (tests/contract)",
    "#problem_place.face_of": "a non-conforming or untagged face (tests/contract)",
    "#problem_place.edge": "a hole in the boundary (tests/contract)",
    "#problem_place.cad_face": "a CAD face without boundary elements (tests/contract)",
    "#problem_place.group": "a group whose area is off (tests/contract)",
    "#problem_place.mesh_area": "a CAD face or group whose area is off (tests/contract)",
    "#problem_place.cad_area": "a CAD face or group whose area is off (tests/contract)",
    "#stats_blade_sector.sections_resampled_from": "sections with different point counts",
    "#stats_blade_sector.surface_notes": "a passage check that notes something (a thin passage)",
    "#stats_heal.fixes.solids_fused": "fluid: box around a body of several solids",
    "#stats_heal.fixes.symmetry_plane": "fluid: box with symmetry_plane (a half model given as a body)",
    "#stats_heal.fixes.unify_rejected": "same-domain unification breaking the solid",
    "#stats_heal.fixes.enclosed_regions_dropped": "a fluid region in pieces (tests/heal: a hollow body not sewn again)",
    "#stats_heal.fixes.planar_holes_capped": "a surface model with planar openings (tests/heal: a box missing a face)",
    "#stats_heal.fixes.regions_outside_dropped": "a given shell outside the outer one (tests/heal: two boxes apart)",
    "#stats_heal.fixes.repairs_skipped": "a closed input every tolerance tried opens",
    "#stats_heal.fixes.sewing_gap_measured": "a surface model with gaps (tests/heal: a face 1e-3 apart)",
    "#stats_heal.fixes.tolerance_lowered": "a closed input the tolerance opens (a small feature in a large domain)",
    "#stats_tet.tet.switches_retry": "TetGen crashing on a surface that does not cross itself",
    "#stats_heal.self_intersections_touching": "a solid whose faces touch within self_intersection_tolerance (the A319)",
    "#stats_heal.self_intersection_check_aborted": "OpenCASCADE's self-intersection checker failing",
    "#stats_medial.uv_polygons": "faces whose parameter-plane outline needs fixing (some corpus STEP files)",
    "#stats_optimise.optimise.untangle.unrepaired.listed[]": "elements the untangling cannot repair",
    "#stats_shell.junction_chains_averaged": "a junction chain ending on a third wall face (DLR-F6's pylon)",
    "#stats_shell.maximin_vertices": "a wall vertex given the maximin direction",
    "#stats_shell.not_honoured.limited_by_face_width": "wall faces narrower than the layer",
    "#stats_shell.not_honoured.thinned_for_crossings": "a shell surface crossing itself before thinning",
    "#stats_shell.resampled_faces": "faces whose shell samples are taken from the field at the points",
    "#stats_shell.self_intersection_at": "a shell surface left crossing itself",
    "#stats_shell.self_intersection_kinds.*": "a shell surface left crossing itself",
    "#stats_shell.unsampled": "a wall face whose shell surface cannot be sampled",
}


def under(path, key):
    return path == key or path.startswith(key + ".") or path.startswith(key + "[")


failures = []


def check(cond, what):
    print(("ok:   " if cond else "FAIL: ") + what)
    if not cond:
        failures.append(what)


def run(work, name, args, expect):
    """meshflow ARGS in WORK/NAME; returns the parsed report(s) written under WORK/NAME/out."""
    d = os.path.join(work, name)
    os.makedirs(d, exist_ok=True)
    t0 = time.time()
    p = subprocess.run([EXE] + args + ["--out", os.path.join(d, "out")], cwd=d, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=600)
    check(p.returncode == expect, f"{name}: exit {p.returncode} (expected {expect}) in {time.time() - t0:.1f} s"
          + ("" if p.returncode == expect else ":\n" + p.stdout[-3000:]))
    reports = []
    for dirpath, _, files in os.walk(os.path.join(d, "out")):
        if "report.json" in files:
            with open(os.path.join(dirpath, "report.json")) as f:
                reports.append((f"{name}:{os.path.relpath(dirpath, d)}", json.load(f)))
    check(reports, f"{name}: wrote report.json")
    return reports


def write(path, text):
    with open(path, "w") as f:
        f.write(text)


def start_remote(work):
    port_file = os.path.join(work, "remote.port")
    srv = subprocess.Popen(["/usr/bin/python3", os.path.join(ROOT, "tests", "remote", "tiny_server.py"), port_file,
                            os.path.join(work, "remote-store")])
    for _ in range(200):
        if os.path.exists(port_file):
            with open(port_file) as f:
                return srv, "http://127.0.0.1:" + f.read().strip()
        time.sleep(0.05)
    srv.kill()
    raise RuntimeError("tiny_server.py did not start")


def all_runs(work):
    reports = []
    demo_cache = os.path.join(work, "demo-cache")
    srv, url = start_remote(work)
    try:
        reports += run(work, "demo", ["run", DEMO] + SMALL + ["--cache", demo_cache, "--remote-cache", url], 0)
        reports += run(work, "remote", ["run", DEMO] + SMALL + ["--cache", os.path.join(work, "remote-cache"),
                                                               "--remote-cache", url], 0)
    finally:
        srv.kill()
        srv.wait()
    reports += run(work, "rerun", ["run", DEMO] + SMALL + ["--cache", demo_cache], 0)
    # corrupt balance's object (small; its stage reruns in a second, downstream stays cached)
    demo_report = dict(reports[0][1])
    digest = demo_report["outputs"]["divisions"]["digest"]
    obj = os.path.join(demo_cache, "objects", digest[:2], digest)
    os.chmod(obj, 0o644)
    with open(obj, "ab") as f:
        f.write(b" ")
    q = run(work, "quarantine", ["run", DEMO] + SMALL + ["--cache", demo_cache], 0)
    check(any(r.get("quarantined") for _, r in q), "quarantine: report.json lists the quarantined object")
    reports += q
    reports += run(work, "invalid", ["run", DEMO] + SMALL + ["--cache", demo_cache, "--set", "optimise.untangle=false", "--set", "optimise.linearise_invalid=false"], 3)
    reports += run(work, "accepted", ["run", DEMO] + SMALL + ["--cache", demo_cache, "--set", "optimise.untangle=false", "--set", "optimise.linearise_invalid=false",
                                                             "--allow-invalid"], 0)
    reports += run(work, "failed", ["run", DEMO] + SMALL + ["--cache", demo_cache, "--set", "tet.max_elements=10"], 1)

    with open(DEMO) as f:
        matrix_wf = f.read().replace("golden: {path: ../golden/naca_wingtip",
                                     "matrix:\n  split.layers: [2, 3]\ngolden: {path: golden")
    write(os.path.join(work, "matrix.yaml"), matrix_wf)
    reports += run(work, "matrix", ["run", os.path.join(work, "matrix.yaml")] + SMALL + ["--cache", demo_cache], 0)

    step_file = os.path.join(work, "demo", "out", "shape.step")
    write(os.path.join(work, "step.yaml"), f"""meshflow: 1
name: step-import
stages:
  geometry: {{kind: step, with: {{file: {step_file}, units: m}}}}
  heal: {{kind: heal, needs: [geometry]}}
outputs:
  shape: {{from: heal, formats: [brep]}}
""")
    reports += run(work, "step", ["run", os.path.join(work, "step.yaml"), "--cache", os.path.join(work, "cache")], 0)

    write(os.path.join(work, "wing_body.yaml"), """meshflow: 1
name: wing-body-geometry
stages:
  geometry: {kind: wing_body}
  heal: {kind: heal, needs: [geometry]}
outputs:
  shape: {from: heal}
""")
    reports += run(work, "wing_body", ["run", os.path.join(work, "wing_body.yaml"), "--cache", os.path.join(work, "cache")], 0)

    # the demo's wing with its box sides y = -3 / y = 3 periodic: a translation (no divisions to check)
    write(os.path.join(work, "translation.yaml"), """meshflow: 1
name: periodic-translation
stages:
  geometry:
    kind: naca_wing
    with:
      farfield_chords: 3
      tag_overrides:
        - {tag: periodic_lo, plane: {point: [0, -3, 0], normal: [0, 1, 0]}}
        - {tag: periodic_hi, plane: {point: [0, 3, 0], normal: [0, 1, 0]}}
  periodic_match: {kind: periodic_match, needs: [geometry]}
outputs:
  periodic: {from: periodic_match}
""")
    reports += run(work, "translation", ["run", os.path.join(work, "translation.yaml"), "--cache", os.path.join(work, "cache")], 0)

    csv = os.path.join(work, "row.csv")
    subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "scripts", "synthetic-blade.py"), csv, "--units-comment", "cm",
                    "--sections", "4", "--points", "24", "--hub", "15", "--tip", "18", "--chord", "6", "6.5",
                    "--stagger", "30", "40"], check=True, stdout=subprocess.DEVNULL)
    write(os.path.join(work, "row.yaml"), """meshflow: 1
name: blade-row
stages:
  geometry:
    kind: blade_sector
    with: {file: row.csv, format: csv, blades: 36, upstream: 1.0, downstream: 1.0}
  heal: {kind: heal, needs: [geometry]}
  medial: {kind: medial, needs: [heal], with: {passes: 1, spacing: 0.04}}
  shell: {kind: shell, needs: [heal, medial], with: {thickness: 0.15, thickness_relative_to: length}}
  balance: {kind: balance, needs: [heal, shell], with: {sizes_relative_to: length, min_size: 0.065, max_size: 0.15}}
  periodic_match: {kind: periodic_match, needs: [heal, balance]}
outputs:
  periodic: {from: periodic_match}
""")
    reports += run(work, "blade", ["run", os.path.join(work, "row.yaml"), "-j", "2", "--threads", "2",
                                   "--cache", os.path.join(work, "cache")], 0)
    return reports


def field_paths(schema, node, path, out, visited):
    """The paths of the fields the schema documents: from the report's root ('stages[].status') or
    from the definition that declares them ('#mesh.nodes', '#heal.fixes.sewing.deleted_faces')."""
    if "$ref" in node:
        name = node["$ref"][len("#/$defs/"):]
        if name not in visited:
            visited.add(name)
            field_paths(schema, schema["$defs"][name], "#" + name, out, visited)
    for k, sub in node.get("properties", {}).items():
        p = f"{path}.{k}" if path else k
        out.add(p)
        field_paths(schema, sub, p, out, visited)
    if isinstance(node.get("items"), dict):
        field_paths(schema, node["items"], path + "[]", out, visited)
    if isinstance(node.get("additionalProperties"), dict):
        field_paths(schema, node["additionalProperties"], path + ".*", out, visited)
    for key in ("allOf", "anyOf", "oneOf"):
        for sub in node.get(key, []):
            field_paths(schema, sub, path, out, visited)
    for key in ("then", "else"):
        if key in node:
            field_paths(schema, node[key], path, out, visited)


def seen_paths(value, schema_node, schema, path, out):
    """The documented paths a report holds: walks the value along the schema."""
    if "$ref" in schema_node:
        name = schema_node["$ref"][len("#/$defs/"):]
        seen_paths(value, schema["$defs"][name], schema, "#" + name, out)
    for key in ("allOf", "anyOf", "oneOf"):
        for sub in schema_node.get(key, []):
            if key == "allOf" or jsonschema.Draft202012Validator(dict(sub, **{"$defs": schema["$defs"]})).is_valid(value):
                seen_paths(value, sub, schema, path, out)
    if "if" in schema_node:
        cond = jsonschema.Draft202012Validator(dict(schema_node["if"], **{"$defs": schema["$defs"]})).is_valid(value)
        branch = schema_node.get("then" if cond else "else")
        if branch:
            seen_paths(value, branch, schema, path, out)
    if isinstance(value, dict):
        props = schema_node.get("properties", {})
        for k, v in value.items():
            if k in props:
                p = f"{path}.{k}" if path else k
                out.add(p)
                seen_paths(v, props[k], schema, p, out)
            elif isinstance(schema_node.get("additionalProperties"), dict):
                seen_paths(v, schema_node["additionalProperties"], schema, path + ".*", out)
    if isinstance(value, list) and isinstance(schema_node.get("items"), dict):
        for v in value:
            seen_paths(v, schema_node["items"], schema, path + "[]", out)


def main():
    with open(os.path.join(ROOT, "schemas", "report.schema.json")) as f:
        schema = json.load(f)
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    work = KEEP or tempfile.mkdtemp(prefix="meshflow-report-")
    if KEEP:
        shutil.rmtree(KEEP, ignore_errors=True)
        os.makedirs(KEEP)
    try:
        reports = all_runs(work)
        kinds = set()
        for name, r in reports:
            errors = sorted(validator.iter_errors(r), key=lambda e: list(e.absolute_path))
            check(not errors, f"{name}: report.json validates" + "".join(
                f"\n    at {'/'.join(map(str, e.absolute_path))}: {e.message[:300]}" for e in errors[:20]))
            kinds |= {s["kind"] for s in r.get("stages", []) if s.get("status") in ("ran", "cached", "invalid")}
        listed = subprocess.run([EXE, "kinds"], stdout=subprocess.PIPE, text=True).stdout
        all_kinds = {line.split(" ")[0] for line in listed.splitlines() if " (version " in line and not line.startswith(" ")}
        check(len(all_kinds) >= 14 and all_kinds <= kinds,
              f"every stage kind ({len(all_kinds)}) ran in some report: missing {sorted(all_kinds - kinds)}")
        documented, seen = set(), set()
        field_paths(schema, schema, "", documented, set())
        for _, r in reports:
            seen_paths(r, schema, schema, "", seen)
        never = sorted(p for p in documented - seen if not any(under(p, k) for k in NOT_EXERCISED))
        check(not never, f"every documented field appears in some report ({len(documented)} documented): never seen:"
              + "".join("\n    " + p for p in never))
        stale = sorted(k for k in NOT_EXERCISED if any(under(p, k) for p in seen))
        check(not stale, f"NOT_EXERCISED lists only fields no run writes (remove the others from it): {stale}")
        unknown = sorted(k for k in NOT_EXERCISED if not any(under(p, k) for p in documented))
        check(not unknown, f"NOT_EXERCISED names documented fields only: {unknown}")
    finally:
        if not KEEP:
            shutil.rmtree(work, ignore_errors=True)
    print(f"{len(failures)} failure(s)")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
