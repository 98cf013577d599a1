#!/usr/bin/python3
"""Independent validity check of a meshflow VTU with VTK's own Lagrange cells.

For every Lagrange tet, wedge and hexahedron of the file, det J is evaluated at a lattice of
parametric sample points with VTK's basis derivatives (vtkLagrange*::InterpolateDerivs), and the
cells with det J <= 0 at some sample are counted. Sampling is not a proof (meshflow's Bezier
check is); this is the cross-check that an independent implementation of the same elements,
node ordering included, finds no inverted sample either.

Usage: vtk_lagrange_check.py FILE.vtu  -> prints one line per cell type:
   <vtk class> <cells> <cells with det J <= 0 at a sample> <min over cells of min/max det J>
"""
import sys

import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy


def lattice(kind, k):
    pts = []
    for i in range(k + 1):
        for j in range(k + 1):
            for l in range(k + 1):
                r, s, t = i / k, j / k, l / k
                if kind in ("wedge", "tet") and r + s > 1:
                    continue
                if kind == "tet" and r + s + t > 1:
                    continue
                pts.append((r, s, t))
    return pts


def main(path):
    rd = vtk.vtkXMLUnstructuredGridReader()
    rd.SetFileName(path)
    rd.Update()
    g = rd.GetOutput()
    X = vtk_to_numpy(g.GetPoints().GetData()).astype(float)
    types = vtk_to_numpy(g.GetCellTypesArray())
    cells = g.GetCells()
    offsets = vtk_to_numpy(cells.GetOffsetsArray())
    conn = vtk_to_numpy(cells.GetConnectivityArray())
    kinds = {vtk.VTK_LAGRANGE_TETRAHEDRON: "tet", vtk.VTK_LAGRANGE_WEDGE: "wedge",
             vtk.VTK_LAGRANGE_HEXAHEDRON: "hex"}
    for vt, kind in kinds.items():
        ids = np.nonzero(types == vt)[0]
        if len(ids) == 0:
            continue
        n = offsets[ids[0] + 1] - offsets[ids[0]]
        assert np.all(offsets[ids + 1] - offsets[ids] == n), "mixed orders"
        cell = g.GetCell(int(ids[0]))
        # basis derivatives at the samples, the same for every cell of this type and order
        interleaved = cell.GetClassName() == "vtkLagrangeHexahedron"  # see tests/io/io_test.cpp
        D = []
        for p in lattice(kind, 6):
            d = [0.0] * (3 * n)
            cell.InterpolateDerivs(p, d)
            D.append(np.array(d).reshape(n, 3).T if interleaved else np.array(d).reshape(3, n))
        D = np.array(D)  # (samples, 3, n)
        bad, ratio = 0, np.inf
        # in chunks of cells, so that a mesh of millions of nodes (Rotor 67 at P = 4) fits in memory
        chunk = max(1, 4000000 // (len(D) * n))
        for a in range(0, len(ids), chunk):
            c = ids[a:a + chunk]
            P = X[conn[offsets[c][:, None] + np.arange(n)]]  # (cells, n, 3)
            J = np.matmul(D[None, :, :, :], P[:, None, :, :])  # (cells, samples, 3 param, 3 x): J transposed, same det
            det = np.linalg.det(J)
            bad += int((det.min(axis=1) <= 0).sum())
            ratio = min(ratio, float((det.min(axis=1) / np.abs(det).max(axis=1)).min()))
        print(cell.GetClassName(), len(ids), bad, "%.6g" % ratio)


if __name__ == "__main__":
    main(sys.argv[1])
