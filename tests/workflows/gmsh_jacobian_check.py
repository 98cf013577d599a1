#!/usr/bin/python3
"""Gmsh's own verdict on a mesh: Plugin(AnalyseMeshQuality) with the Jacobian determinant,
counted per element type. Prints lines "<gmsh type name> <elements> <elements with minJ/maxJ <= 0>".
Usage: gmsh_jacobian_check.py FILE.msh
"""
import collections
import sys

import gmsh

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.option.setNumber("General.AbortOnError", 0)
gmsh.open(sys.argv[1])
gmsh.plugin.setNumber("AnalyseMeshQuality", "JacobianDeterminant", 1)
gmsh.plugin.setNumber("AnalyseMeshQuality", "CreateView", 1)
gmsh.plugin.run("AnalyseMeshQuality")
_, keys, data, _, _ = gmsh.view.getModelData(gmsh.view.getTags()[-1], 0)
flagged = {k for k, d in zip(keys, data) if d[0] <= 0}
total, bad = collections.Counter(), collections.Counter()
for t in gmsh.model.mesh.getElementTypes(3):
    try:
        name = gmsh.model.mesh.getElementProperties(t)[0].split()[0]
    except Exception:  # Gmsh 4.8 cannot describe some high-order types (order-4 pyramids: 119)
        name = {118: "Pyramid", 119: "Pyramid", 120: "Pyramid"}.get(t, str(t))
    tags, _ = gmsh.model.mesh.getElementsByType(t)
    total[name] += len(tags)
    bad[name] += sum(1 for e in tags if e in flagged)
for name in sorted(total):
    print(name, total[name], bad[name])
