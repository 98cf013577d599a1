#!/usr/bin/python3
"""Gmsh's own verdict on a mesh: Plugin(AnalyseMeshQuality) (Jacobian determinant range per
element) with General.AbortOnError = 0. Prints "ANALYSE {json}" with the plugin's log lines and
the number of elements it reports with a non-positive minimum Jacobian (from its view)."""
import json, sys, time
import gmsh

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.option.setNumber("General.AbortOnError", 0)
gmsh.logger.start()
t0 = time.time()
res = {"file": sys.argv[1]}
try:
    gmsh.open(sys.argv[1])
    gmsh.plugin.setNumber("AnalyseMeshQuality", "JacobianDeterminant", 1)
    gmsh.plugin.setNumber("AnalyseMeshQuality", "IGEMeasure", 0)
    gmsh.plugin.setNumber("AnalyseMeshQuality", "ICNMeasure", 0)
    gmsh.plugin.setNumber("AnalyseMeshQuality", "Recompute", 1)
    gmsh.plugin.setNumber("AnalyseMeshQuality", "CreateView", 1)
    gmsh.plugin.setNumber("AnalyseMeshQuality", "DimensionOfElements", 3)
    gmsh.plugin.run("AnalyseMeshQuality")
    # the view holds per element [min J/J0, max J/J0] ("minJ/maxJ" ratio view on some versions)
    tags = gmsh.view.getTags()
    res["views"] = []
    for v in tags:
        name = gmsh.option.getString("View[%d].Name" % gmsh.view.getIndex(v))
        dtype, etags, data, _, nc = gmsh.view.getModelData(v, 0)
        mins = [d[0] for d in data]
        res["views"].append({"name": name, "n": len(mins),
                             "nonpositive": sum(1 for m in mins if m <= 0),
                             "nonpositive_tags": [int(t) for t, m in zip(etags, mins) if m <= 0][:50],
                             "min": min(mins) if mins else None})
except Exception as e:
    res["error"] = str(e)
res["log"] = [l for l in gmsh.logger.get() if "nalyse" in l or "rror" in l or "arning" in l or "Jac" in l
              or "element" in l.lower()][-25:]
res["time_s"] = round(time.time() - t0, 2)
print("ANALYSE " + json.dumps(res), flush=True)
gmsh.finalize()
