#!/usr/bin/python3
"""Gmsh half of the meshflow/Gmsh side-by-side benchmark (issue 8).

Closest equivalent Gmsh 4.8 can make of meshflow's mesh: a prismatic boundary layer made by
extruding the wall surface mesh (10 layers, geometric ratio 1.5), tetrahedra outside, order P,
then HighOrderOptimize.

Route (Gmsh's `geo.extrudeBoundaryLayer` only extrudes built-in/discrete entities, not OCC ones):
  1. import the CAD with OCC, scale it, drop the far-field box faces, mesh the wall faces in 2D;
  2. write that surface mesh and reopen it: the walls become discrete entities (+createGeometry);
  3. extrudeBoundaryLayer(walls, numElements=[1]*L, heights=cumulative geometric, recombine);
  4. rebuild the far-field box in the built-in kernel (its faces are planes: exact), the box face
     the walls touch (tunnel floor / symmetry plane) gets the layer's footprint as a hole;
     volume between the layer's top surface and the box, meshed with tets;
  5. setOrder(P), HighOrderOptimize (2 = elastic+optimization, 4 = fast curving, 0 = none).
Every step is timed; a JSON line with statistics is printed at the end ("STATS {...}").
"""
import argparse, json, math, os, sys, tempfile, time

import gmsh

ap = argparse.ArgumentParser()
ap.add_argument("cad")
ap.add_argument("out")
ap.add_argument("--scale", type=float, default=1e-3, help="unit scale applied to the CAD (mm->m: 1e-3)")
ap.add_argument("--walls", default="auto",
                help="comma-separated OCC face tags or ranges (1-123) to extrude, or 'auto' = every face not lying on the bounding box")
ap.add_argument("--heal", type=int, default=0, help="OCC healing on import (OCCFixDegenerated/SewFaces/MakeSolids)")
ap.add_argument("--layers", type=int, default=10)
ap.add_argument("--ratio", type=float, default=1.5)
ap.add_argument("--first-height", type=float, default=4.4e-4, help="first layer height (scaled units)")
ap.add_argument("--wall-size", type=float, default=0.05, help="max element size on the walls (scaled units)")
ap.add_argument("--wall-min", type=float, default=0.0, help="min element size on the walls")
ap.add_argument("--curv", type=int, default=12, help="Mesh.MeshSizeFromCurvature (elements per 2*pi)")
ap.add_argument("--far-size", type=float, default=0.5, help="element size at the far-field box")
ap.add_argument("--order", type=int, default=4)
ap.add_argument("--hoopt", type=int, default=2, help="Mesh.HighOrderOptimize (0 none, 2 elastic+opt, 4 fast curving)")
ap.add_argument("--classify-angle", type=float, default=40.0, help="classifySurfaces angle (deg)")
ap.add_argument("--threads", type=int, default=1)
ap.add_argument("--no-bl", action="store_true", help="fallback: no layer at all, tets only")
a = ap.parse_args()

T = {}
t0 = time.time()
def lap(name):
    global t0
    t = time.time(); T[name] = round(t - t0, 3); t0 = t

stats = {"cad": a.cad, "args": vars(a), "gmsh": None, "stage": "start"}
log = []
def out(code):
    stats["times_s"] = T
    stats["log_tail"] = [l for l in log if "rror" in l or "arning" in l][-15:]
    print("STATS " + json.dumps(stats), flush=True)
    sys.exit(code)

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 1)
gmsh.option.setNumber("General.NumThreads", a.threads)
gmsh.logger.start()
stats["gmsh"] = gmsh.option.getString("General.Version")
try:
    # ---------------------------------------------------------------- 1. CAD, wall surface mesh
    stats["stage"] = "import"
    if a.heal:
        for o in ("Geometry.OCCFixDegenerated", "Geometry.OCCSewFaces", "Geometry.OCCMakeSolids"):
            gmsh.option.setNumber(o, 1)
    gmsh.model.add("cad")
    gmsh.model.occ.importShapes(a.cad)
    if a.scale != 1.0:
        gmsh.model.occ.dilate(gmsh.model.occ.getEntities(), 0, 0, 0, a.scale, a.scale, a.scale)
    gmsh.model.occ.synchronize()
    bb = gmsh.model.getBoundingBox(-1, -1)
    stats["bbox"] = bb
    stats["cad_entities"] = [len(gmsh.model.getEntities(d)) for d in range(4)]
    tol = 1e-6 * max(bb[3] - bb[0], bb[4] - bb[1], bb[5] - bb[2])
    faces = [t for _, t in gmsh.model.getEntities(2)]
    def on_box(t):
        b = gmsh.model.getBoundingBox(2, t)
        for k in range(3):
            if abs(b[k] - b[k + 3]) < tol and (abs(b[k] - bb[k]) < tol or abs(b[k] - bb[k + 3]) < tol):
                return True
        return False
    if a.walls == "auto":
        walls = [t for t in faces if not on_box(t)]
    else:
        walls = []
        for x in a.walls.split(","):
            lo, _, hi = x.partition("-")
            walls += list(range(int(lo), int(hi or lo) + 1))
    stats["walls"] = walls
    lap("import")

    stats["stage"] = "surface mesh"
    gmsh.model.occ.remove([(2, t) for t in faces if t not in walls] +
                          [(3, t) for _, t in gmsh.model.getEntities(3)], recursive=False)
    gmsh.model.occ.synchronize()
    # wall curves used by one wall face only: the footprint on the box (tunnel floor, symmetry plane)
    use = {}
    for t in walls:
        for _, c in gmsh.model.getBoundary([(2, t)], oriented=False):
            use.setdefault(abs(c), []).append(t)
    foot_curves = [c for c, us in use.items() if len(us) == 1]
    gmsh.option.setNumber("Mesh.MeshSizeMax", a.wall_size)
    gmsh.option.setNumber("Mesh.MeshSizeMin", a.wall_min)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", a.curv)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.model.mesh.generate(2)
    # which side is the fluid: signed volume of the wall mesh closed by its (planar) footprint,
    # taken from a point of the footprint plane (the cap adds nothing); > 0: normals point out
    # of the body into the fluid, extrude with positive heights.
    ntag, nxyz, _ = gmsh.model.mesh.getNodes()
    npos = {int(t): i for i, t in enumerate(ntag)}
    o = [0.0, 0.0, 0.0]
    if foot_curves:
        fn, fx, _ = gmsh.model.mesh.getNodes(1, foot_curves[0], includeBoundary=True)
        o = list(fx[0:3])
    V = 0.0
    for _, t in gmsh.model.getEntities(2):
        ets, _, enodes = gmsh.model.mesh.getElements(2, t)
        for et, en in zip(ets, enodes):
            for k in range(0, len(en), 3):
                p = [[nxyz[3 * npos[int(en[k + j])] + i] - o[i] for i in range(3)] for j in range(3)]
                V += (p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0])
                      + p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0])) / 6.0
    stats["wall_signed_volume"] = V
    # Gmsh orients the triangles of the faces consistently (checked: every interior mesh edge
    # is used in both directions); count violations, the extrusion normals would cancel there
    dirs = {}
    for _, t in gmsh.model.getEntities(2):
        ets, _, enodes = gmsh.model.mesh.getElements(2, t)
        for en in enodes:
            for k in range(0, len(en), 3):
                for i in range(3):
                    dirs[(int(en[k + i]), int(en[k + (i + 1) % 3]))] = dirs.get((int(en[k + i]), int(en[k + (i + 1) % 3])), 0) + 1
    stats["wall_edges_same_direction"] = sum(1 for e, n in dirs.items() if n > 1)
    side = 1.0 if V > 0 else -1.0
    lap("surface_mesh")
    tmp = tempfile.NamedTemporaryFile(suffix=".msh", delete=False).name
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.write(tmp)
    gmsh.model.remove()

    # ---------------------------------------------------------------- 2. discrete walls
    stats["stage"] = "discrete walls"
    gmsh.merge(tmp)
    os.unlink(tmp)
    # Walls reopened from MSH are discrete entities whose curves have no begin/end points in
    # the built-in kernel, so extrudeBoundaryLayer does not extrude them ("Cannot extrude curve
    # with no begin/end points" if passed explicitly; "Could not find extruded node" at meshing
    # otherwise). classifySurfaces rebuilds the discrete topology (faces split at sharp edges,
    # > --classify-angle) from the mesh itself, as Gmsh's aneurysm example does. No
    # createGeometry(): it would make the walls remeshable and generate(3) would remesh them.
    import math as _m
    gmsh.model.mesh.classifySurfaces(a.classify_angle * _m.pi / 180, True, False)
    wall_ents = gmsh.model.getEntities(2)
    stats['discrete_entities'] = [len(gmsh.model.getEntities(d)) for d in range(4)]
    _, tri, _ = gmsh.model.mesh.getElements(2)
    stats["wall_triangles"] = int(sum(len(x) for x in tri))
    lap("discrete")

    top = []
    if not a.no_bl:
        # ------------------------------------------------------------ 3. boundary layer
        stats["stage"] = "extrudeBoundaryLayer"
        d = [a.first_height * (a.ratio ** (k + 1) - 1) / (a.ratio - 1) for k in range(a.layers)]
        stats["bl_thickness"] = d[-1]
        # Sign: outward normal of the wall surface mesh points into the body or into the fluid
        # depending on the orientation of the OCC faces; the extrusion side is checked below.
        gmsh.option.setNumber("Geometry.ExtrudeReturnLateralEntities", 0)
        ext = gmsh.model.geo.extrudeBoundaryLayer(wall_ents, [1] * a.layers, [side * x for x in d], True)
        gmsh.model.geo.synchronize()
        # top surfaces = the (2, .) entry just before each (3, .) entry
        top = [e for e in ext if e[0] == 2]
        stats["bl_volumes"] = sum(1 for e in ext if e[0] == 3)
        lap("extrude_bl")

    # ---------------------------------------------------------------- 4. far-field box
    # The layer's top curves have no begin/end points in the built-in kernel (discrete source),
    # so a GEO plane surface "box side minus footprint" cannot be built from them (tried:
    # "Unknown curve loop" / "Unable to recover the edge ... on curve"). Instead: mesh the layer,
    # take the loop(s) of boundary edges of its top surface, build box + footprint polygon in a
    # second OCC model (one mesh edge per polygon segment, so the nodes coincide), copy that
    # surface mesh back as discrete surfaces sharing the footprint nodes, and close the outer
    # volume with geo.addSurfaceLoop/addVolume (as Gmsh's t13 does for discrete surfaces).
    import numpy as np
    stats["stage"] = "mesh layer"
    gmsh.model.mesh.generate(3)
    # freeze the layer: reopen its mesh so that the final generate(3) does not re-extrude it
    tmp2 = tempfile.NamedTemporaryFile(suffix=".msh", delete=False).name
    gmsh.option.setNumber("Mesh.SaveAll", 1)
    gmsh.write(tmp2)
    gmsh.model.remove()
    gmsh.merge(tmp2)
    os.unlink(tmp2)
    wall_ents = [e for e in wall_ents if e in gmsh.model.getEntities(2)]
    lap("mesh_layer")
    stats["stage"] = "outer box"
    x0, y0, z0, x1, y1, z1 = bb
    shell_tags = [t for _, t in (top if top else wall_ents)]
    edges = {}
    for t in shell_tags:
        _, _, en = gmsh.model.mesh.getElements(2, t)
        for arr in en:
            for k in range(0, len(arr), 3):
                for i in range(3):
                    p, q = int(arr[k + i]), int(arr[k + (i + 1) % 3])
                    key = (min(p, q), max(p, q))
                    edges[key] = edges.get(key, 0) + 1
    bedges = [e for e, n in edges.items() if n == 1]
    adj = {}
    for p, q in bedges:
        adj.setdefault(p, []).append(q)
        adj.setdefault(q, []).append(p)
    loops, seen = [], set()
    for start in adj:
        if start in seen:
            continue
        lp, prev, cur = [start], None, start
        seen.add(start)
        while True:
            nxt = [n for n in adj[cur] if n != prev]
            if not nxt or nxt[0] == start:
                break
            prev, cur = cur, nxt[0]
            if cur in seen:
                break
            lp.append(cur); seen.add(cur)
        loops.append(lp)
    stats["footprint_loops"] = [len(l) for l in loops]
    ntag, nxyz, _ = gmsh.model.mesh.getNodes()
    X = {int(t): np.array(nxyz[3 * i:3 * i + 3]) for i, t in enumerate(ntag)}
    sides = [(ax, end) for ax in range(3) for end in (0, 1)]
    holes = {s_: [] for s_ in sides}
    devs = []
    for lp in loops:
        P_ = np.array([X[n] for n in lp])
        best = min(sides, key=lambda s_: np.abs(P_[:, s_[0]] - bb[s_[0] + 3 * s_[1]]).max())
        dev = float(np.abs(P_[:, best[0]] - bb[best[0] + 3 * best[1]]).max())
        devs.append(dev)
        holes[best].append(lp)
    stats["footprint_offplane_max"] = max(devs) if devs else 0.0
    bl_thick = stats.get("bl_thickness", 0.0)
    if devs and max(devs) > 0.25 * max(bl_thick, 1e-12):
        raise RuntimeError("layer footprint is %.3g off the box side: not planar at the junction" % max(devs))
    # the mesh normals at the junction are not exactly parallel to the box side: move the
    # layer's top footprint nodes onto the side (recorded as footprint_offplane_max)
    for s_, lps in holes.items():
        for lp in lps:
            for n in lp:
                X[n][s_[0]] = bb[s_[0] + 3 * s_[1]]
                gmsh.model.mesh.setNode(n, list(X[n]), [])
    cur_model = gmsh.model.getCurrent()
    gmsh.model.add("box")
    occ = gmsh.model.occ
    box = occ.addBox(x0, y0, z0, x1 - x0, y1 - y0, z1 - z0)
    occ.synchronize()
    bfaces = [t for _, t in gmsh.model.getBoundary([(3, box)], oriented=False)]
    occ.remove([(3, box)])
    seg_curves = []
    final_faces = []
    for t in bfaces:
        fb = gmsh.model.occ.getBoundingBox(2, t)
        tb = 1e-5 * max(x1 - x0, y1 - y0, z1 - z0)  # OCC bounding boxes carry the tolerance
        sd = [s_ for s_ in sides if abs(fb[s_[0]] - fb[s_[0] + 3]) < tb
              and abs(0.5 * (fb[s_[0]] + fb[s_[0] + 3]) - bb[s_[0] + 3 * s_[1]]) < tb]
        hl = holes[sd[0]] if sd else []
        if not hl:
            final_faces.append(t)
            continue
        tools = []
        for lp in hl:
            pts = []
            for n in lp:
                c = X[n].copy(); c[sd[0][0]] = bb[sd[0][0] + 3 * sd[0][1]]
                pts.append(occ.addPoint(*c))
            ls = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
            tools.append((2, occ.addPlaneSurface([occ.addCurveLoop(ls)])))
        res, _ = occ.cut([(2, t)], tools)
        final_faces += [x[1] for x in res]
    occ.synchronize()
    hole_pts = np.array([X[n] for lps in holes.values() for lp in lps for n in lp]) if any(holes.values()) else np.zeros((0, 3))
    hole_tags = [n for lps in holes.values() for lp in lps for n in lp]
    for _, c in gmsh.model.getEntities(1):
        cb = gmsh.model.getBoundingBox(1, c)
        diag = math.dist(cb[0:3], cb[3:6])
        if diag < 0.5 * min(x1 - x0, y1 - y0, z1 - z0):
            gmsh.model.mesh.setTransfiniteCurve(c, 2)
    gmsh.model.mesh.setSize(gmsh.model.getEntities(0), a.far_size)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", a.far_size)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0)
    gmsh.model.mesh.generate(2)
    bn, bx, _ = gmsh.model.mesh.getNodes()
    bx = np.array(bx).reshape(-1, 3)
    faces_mesh = []
    for _, t in gmsh.model.getEntities(2):
        _, _, en = gmsh.model.mesh.getElements(2, t)
        faces_mesh.append([int(x) for x in en[0]])
    gmsh.model.remove()
    gmsh.model.setCurrent(cur_model)
    # map box nodes onto the layer's footprint nodes (same position up to the projection)
    nmap = {}
    newn, newx = [], []
    next_tag = int(max(ntag)) + 1
    for t, c in zip(bn, bx):
        t = int(t)
        if len(hole_pts):
            d = np.abs(hole_pts - c)
            k = int(np.argmin(d.max(axis=1)))
            if d[k].max() <= 1e-6 * max(x1 - x0, y1 - y0, z1 - z0):
                nmap[t] = hole_tags[k]
                continue
        nmap[t] = next_tag; newn.append(next_tag); newx += list(c); next_tag += 1
    if len(hole_pts):
        stats["box_to_footprint_mindist"] = float(min(np.abs(hole_pts - c).max(axis=1).min() for c in bx))
    stats["box_faces"] = len(faces_mesh)
    stats["box_nodes_shared_with_layer"] = sum(1 for t in bn if nmap[int(t)] in set(hole_tags))
    new_surfs = []
    stag = max(t for _, t in gmsh.model.getEntities(2)) + 1
    vdummy = None
    for i, fm in enumerate(faces_mesh):
        st = gmsh.model.addDiscreteEntity(2, stag + i)
        new_surfs.append(st)
        if i == 0:
            gmsh.model.mesh.addNodes(2, st, newn, newx)
        gmsh.model.mesh.addElementsByType(st, 2, [], [nmap[n] for n in fm])
    lap("outer_box")
    stats["stage"] = "mesh 3D"
    sl = gmsh.model.geo.addSurfaceLoop(shell_tags + new_surfs)
    gmsh.model.geo.addVolume([sl])
    gmsh.model.geo.synchronize()
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", a.far_size)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.model.mesh.generate(3)
    lap("mesh_3d")

    # ---------------------------------------------------------------- 5. order P + optimisation
    stats["stage"] = "setOrder"
    gmsh.model.mesh.setOrder(a.order)
    lap("set_order")
    if a.hoopt:
        stats["stage"] = "HighOrderOptimize"
        gmsh.option.setNumber("Mesh.HighOrderOptimize", a.hoopt)
        # Mesh.HighOrderOptimize is applied by generate(), not by the API's setOrder(), so the
        # same methods are called explicitly: 2 = elastic then optimization, 4 = fast curving,
        # 1 = optimization, 3 = elastic.
        for m in {1: ["HighOrder"], 2: ["HighOrderElastic", "HighOrder"], 3: ["HighOrderElastic"],
                  4: ["HighOrderFastCurving"]}[a.hoopt]:
            gmsh.model.mesh.optimize(m)
        lap("ho_optimize")
    stats["stage"] = "stats"

    # statistics: counts by type, first-layer height from the prisms standing on the walls
    counts = {}
    for d in (2, 3):
        ts, tags, _ = gmsh.model.mesh.getElements(d)
        for t, tg in zip(ts, tags):
            try:
                nm = gmsh.model.mesh.getElementProperties(t)[0]
            except Exception:
                nm = "type%d" % t
            counts[nm] = counts.get(nm, 0) + len(tg)
    stats["counts"] = counts
    wall_nodes = set()
    for _, t in wall_ents:
        n, _, _ = gmsh.model.mesh.getNodes(2, t, includeBoundary=True)
        wall_nodes.update(int(x) for x in n)
    tags_all, xyz, _ = gmsh.model.mesh.getNodes()
    pos = {int(t): i for i, t in enumerate(tags_all)}
    h = []
    for d in (3,):
        ts, tags, nodes = gmsh.model.mesh.getElements(d)
        for t, tg, nd in zip(ts, tags, nodes):
            # element types 6 (prism 6), 13, 18, 90, 91, 106 (order 4, 75 nodes), 107...
            if t not in (6, 13, 18, 90, 91, 106, 107, 108, 109):
                continue
            nn = len(nd) // len(tg)
            for e in range(len(tg)):
                v = [int(x) for x in nd[e * nn:e * nn + 6]]
                for lo, hi in ((v[0:3], v[3:6]), (v[3:6], v[0:3])):
                    if all(x in wall_nodes for x in lo):
                        for p, q in zip(lo, hi):
                            i, j = pos[p], pos[q]
                            h.append(math.dist(xyz[3 * i:3 * i + 3], xyz[3 * j:3 * j + 3]))
                        break
    if h:
        h.sort()
        stats["first_height"] = {"min": h[0], "median": h[len(h) // 2], "max": h[-1], "n": len(h)}
    gmsh.model.addPhysicalGroup(3, [t for _, t in gmsh.model.getEntities(3)], 1)
    gmsh.model.addPhysicalGroup(2, [t for _, t in wall_ents], 2)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    gmsh.write(a.out)
    lap("write")
    stats["stage"] = "done"
    log = gmsh.logger.get()
    gmsh.finalize()
    out(0)
except Exception as e:
    stats["error"] = str(e)
    try:
        log = gmsh.logger.get()
        stats["last_error"] = gmsh.logger.getLastError()
    except Exception:
        pass
    out(1)
