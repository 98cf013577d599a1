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


def pyramid_samples(n=12):
    """Points of the reference pyramid (base [-1,1]^2 at z=0, apex (0,0,1)), z up to 0.999."""
    pts = []
    for k in range(n + 1):
        z = 0.999 * k / n
        for i in range(n + 1):
            for j in range(n + 1):
                pts += [(-1 + 2 * i / n) * (1 - z), (-1 + 2 * j / n) * (1 - z), z]
    return pts


# Gmsh 4.8's AnalyseMeshQuality returns exactly 0 for curved pyramids whose det J its own shape
# functions find positive everywhere (the demo at order 2: 18 of 25 pyramids, 0.0 each, while
# getJacobians at 2,197 points of each finds min det / max det > 0). A pyramid is flagged only
# when Gmsh's own getJacobians confirms a non-positive det J at a sample point.
for t in gmsh.model.mesh.getElementTypes(3):
    if t not in (7, 14, 118, 119, 120):  # pyramids of orders 1-4 (and 5)
        continue
    tags, _ = gmsh.model.mesh.getElementsByType(t)
    suspects = [e for e in tags if e in flagged]
    if not suspects:
        continue
    _, det, _ = gmsh.model.mesh.getJacobians(t, pyramid_samples())
    per = len(det) // len(tags)
    for i, e in enumerate(tags):
        if e in flagged and min(det[i * per:(i + 1) * per]) > 0:
            flagged.discard(e)
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
