#!/usr/bin/python3
"""Cell volumes of a mesh file as VTK itself computes them (vtkCellSizeFilter).

Reads a VTU with vtkXMLUnstructuredGridReader, or a CGNS file with vtkCGNSReader (every base,
the boundary patches loaded too), and prints for each VTK cell class of the 3D cells:
   <class> <cells> <cells with volume <= 0> <total volume, %.17g>
and for a CGNS file one more line per boundary patch the reader produced:
   patch <name> <cells>
VTK integrates a cell by splitting it into linear tetrahedra at its points, so the total is
exact for straight-sided cells of any order and an approximation for curved ones.

Usage: vtk_cell_volumes.py FILE.vtu|FILE.cgns
"""
import sys

import vtk
from vtk.util.numpy_support import vtk_to_numpy


vtk.vtkObject.GlobalWarningDisplayOff()
vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_OFF)


def volumes(grid, out):
    f = vtk.vtkCellSizeFilter()
    f.SetInputData(grid)
    f.ComputeVertexCountOff(), f.ComputeLengthOff(), f.ComputeAreaOff(), f.ComputeVolumeOn()
    f.Update()
    g = f.GetOutput()
    vol = vtk_to_numpy(g.GetCellData().GetArray("Volume"))
    for c in range(g.GetNumberOfCells()):
        if g.GetCell(c).GetCellDimension() != 3:
            continue
        name = g.GetCell(c).GetClassName()
        n, bad, total = out.get(name, (0, 0, 0.0))
        out[name] = (n + 1, bad + int(vol[c] <= 0), total + float(vol[c]))


def leaves(block, path=""):
    """(path, dataset) of every vtkUnstructuredGrid in a multiblock tree"""
    if isinstance(block, vtk.vtkMultiBlockDataSet):
        for i in range(block.GetNumberOfBlocks()):
            meta = block.GetMetaData(i) if block.HasMetaData(i) else None
            name = meta.Get(vtk.vtkCompositeDataSet.NAME()) if meta else str(i)
            yield from leaves(block.GetBlock(i), path + "/" + str(name))
    elif block is not None and block.IsA("vtkUnstructuredGrid"):
        yield path, block


def main(path):
    out = {}
    if path.endswith(".cgns"):
        r = vtk.vtkCGNSReader()
        r.SetFileName(path)
        r.UpdateInformation()
        r.EnableAllBases()
        r.LoadBndPatchOn()
        r.LoadMeshOn()
        for i in range(r.GetNumberOfFamilyArrays()):
            r.SetFamilyArrayStatus(r.GetFamilyArrayName(i), 1)
        r.Update()
        patches = []
        for p, g in leaves(r.GetOutput()):
            if "/Patches/" in p or "/BCs/" in p or g.GetNumberOfCells() and all(
                    g.GetCell(c).GetCellDimension() == 2 for c in range(g.GetNumberOfCells())):
                patches.append((p.rsplit("/", 1)[-1], g.GetNumberOfCells()))
            else:
                volumes(g, out)
    else:
        r = vtk.vtkXMLUnstructuredGridReader()
        r.SetFileName(path)
        r.Update()
        volumes(r.GetOutput(), out)
        patches = []
    for name, (n, bad, total) in sorted(out.items()):
        print(name, n, bad, "%.17g" % total)
    for name, n in patches:
        print("patch", name, n)


if __name__ == "__main__":
    main(sys.argv[1])
