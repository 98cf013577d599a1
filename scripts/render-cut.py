#!/usr/bin/python3
"""Renders a cut through a meshflow VTU (VTK Lagrange cells, any order) into a PNG, headless.

The cells inside a box that lie behind a plane (or cross it) are kept whole, so the picture shows
the elements' own curved faces at the cut, the way ParaView's "Extract Cells By Region" does:
faces tessellated finely (their curvature visible), coloured by the `scaled_jacobian` cell data,
with every element edge drawn as a curve (sampled from the cell's own Lagrange interpolation).
The camera looks at the plane from its front side (along -normal), parallel projection, framing
the box.

Needs VTK 9 (Debian python3-vtk9) and, without a display, a virtual one: run it as
`xvfb-run -a /usr/bin/python3 scripts/render-cut.py ...` (Debian xvfb; `make pictures` does).

Example (the demo's wing root, cut at x = 0.3 chord):
  render-cut.py out/naca-wingtip/mesh.vtu root.png --point 0.3 0 0 --normal 1 0 0 \
      --box 0.2 0.4 -0.12 0.12 0 0.2 --up 0 1 0
"""
import argparse
import math
import sys

import vtk


def parse():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("vtu", help="a VTU written by meshflow (out/<name>/mesh.vtu)")
    p.add_argument("png", help="the picture to write")
    p.add_argument("--point", type=float, nargs=3, required=True, metavar=("X", "Y", "Z"), help="a point of the cut plane")
    p.add_argument("--normal", type=float, nargs=3, required=True, metavar=("NX", "NY", "NZ"),
                   help="the plane's normal: cells in front of the plane (on the normal's side) are removed")
    p.add_argument("--box", type=float, nargs=6, required=True, metavar=("X0", "X1", "Y0", "Y1", "Z0", "Z1"),
                   help="only cells inside or crossing this box are drawn; the picture frames it")
    p.add_argument("--up", type=float, nargs=3, default=None, metavar=("UX", "UY", "UZ"), help="the picture's up direction")
    p.add_argument("--size", type=int, nargs=2, default=[1200, 800], metavar=("W", "H"), help="picture size in pixels")
    p.add_argument("--subdivision", type=int, default=3, help="tessellation level of curved faces (VTK nonlinear subdivision)")
    p.add_argument("--edge-samples", type=int, default=8, help="segments per drawn element edge")
    p.add_argument("--title", default="", help="text drawn in the top-left corner")
    p.add_argument("--no-edges", action="store_true", help="do not draw element edges")
    return p.parse_args()


def unit(v):
    n = math.sqrt(sum(c * c for c in v))
    if n == 0:
        sys.exit("render-cut: a zero vector was given")
    return [c / n for c in v]


def curved_edges(surface_cells, samples):
    """Polylines along every edge of the (higher-order) surface cells, each edge once."""
    pts = vtk.vtkPoints()
    lines = vtk.vtkCellArray()
    seen = set()
    pc = [0.0, 0.0, 0.0]
    x = [0.0, 0.0, 0.0]
    for i in range(surface_cells.GetNumberOfCells()):
        cell = surface_cells.GetCell(i)
        for k in range(cell.GetNumberOfEdges()):
            e = cell.GetEdge(k)
            ids = e.GetPointIds()
            key = tuple(sorted((ids.GetId(0), ids.GetId(1))))
            if key in seen:
                continue
            seen.add(key)
            w = [0.0] * e.GetNumberOfPoints()
            line = vtk.vtkPolyLine()
            for s in range(samples + 1):
                pc[0] = s / samples
                sub = vtk.reference(0)
                e.EvaluateLocation(sub, pc, x, w)
                line.GetPointIds().InsertNextId(pts.InsertNextPoint(x))
            lines.InsertNextCell(line)
    pd = vtk.vtkPolyData()
    pd.SetPoints(pts)
    pd.SetLines(lines)
    return pd


def main():
    a = parse()
    n = unit(a.normal)
    rd = vtk.vtkXMLUnstructuredGridReader()
    rd.SetFileName(a.vtu)
    rd.Update()
    grid = rd.GetOutput()
    if grid.GetNumberOfCells() == 0:
        sys.exit("render-cut: %s has no cells (is it a VTU file?)" % a.vtu)

    # 3D cells only (the boundary triangles/quads of the VTU would hide the cut)
    dims = grid.GetCellData().GetArray("entity_dim")
    if dims is not None:
        th = vtk.vtkThreshold()
        th.SetInputData(grid)
        th.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_CELLS, "entity_dim")
        th.SetLowerThreshold(3)
        th.SetUpperThreshold(3)
        th.Update()
        vol = th.GetOutput()
    else:
        vol = grid

    box = vtk.vtkBox()
    box.SetBounds(*a.box)
    in_box = vtk.vtkExtractGeometry()
    in_box.SetInputData(vol)
    in_box.SetImplicitFunction(box)
    in_box.ExtractInsideOn()
    in_box.ExtractBoundaryCellsOn()
    plane = vtk.vtkPlane()
    plane.SetOrigin(*a.point)
    plane.SetNormal(*n)
    behind = vtk.vtkExtractGeometry()
    behind.SetInputConnection(in_box.GetOutputPort())
    behind.SetImplicitFunction(plane)
    behind.ExtractInsideOn()  # f(x) = n . (x - p) < 0
    behind.ExtractBoundaryCellsOn()
    behind.Update()
    cells = behind.GetOutput()
    if cells.GetNumberOfCells() == 0:
        sys.exit("render-cut: no cell of %s lies in the box behind the plane: check --box, --point, --normal" % a.vtu)

    surf = vtk.vtkDataSetSurfaceFilter()
    surf.SetInputData(cells)
    surf.SetNonlinearSubdivisionLevel(a.subdivision)
    surf.Update()
    lut = vtk.vtkLookupTable()
    lut.SetHueRange(0.0, 0.66)  # red (poor) .. blue (ideal)
    lut.SetTableRange(0.0, 1.0)
    lut.Build()
    m = vtk.vtkPolyDataMapper()
    m.SetInputConnection(surf.GetOutputPort())
    m.SetScalarModeToUseCellFieldData()
    m.SelectColorArray("scaled_jacobian")
    m.SetLookupTable(lut)
    m.SetScalarRange(0.0, 1.0)
    m.ScalarVisibilityOn()
    m.SetResolveCoincidentTopologyToPolygonOffset()
    faces = vtk.vtkActor()
    faces.SetMapper(m)
    faces.GetProperty().SetAmbient(1.0)  # flat colours: the value is the quality, not the lighting
    faces.GetProperty().SetDiffuse(0.0)

    ren = vtk.vtkRenderer()
    ren.SetBackground(1, 1, 1)
    ren.AddActor(faces)
    if not a.no_edges:
        geo = vtk.vtkUnstructuredGridGeometryFilter()  # the surface as higher-order 2D cells
        geo.SetInputData(cells)
        geo.Update()
        em = vtk.vtkPolyDataMapper()
        em.SetInputData(curved_edges(geo.GetOutput(), a.edge_samples))
        em.ScalarVisibilityOff()
        edges = vtk.vtkActor()
        edges.SetMapper(em)
        edges.GetProperty().SetColor(0.05, 0.05, 0.05)
        edges.GetProperty().SetLineWidth(1.0)
        ren.AddActor(edges)

    bar = vtk.vtkScalarBarActor()
    bar.SetLookupTable(lut)
    bar.SetTitle("scaled Jacobian")
    bar.SetNumberOfLabels(5)
    bar.SetWidth(0.6)
    bar.SetHeight(0.6)
    bar.SetPosition(0.2, 0.2)
    for t in (bar.GetTitleTextProperty(), bar.GetLabelTextProperty()):
        t.SetColor(0, 0, 0)
    side_ren = vtk.vtkRenderer()  # the colour bar in its own strip, beside the mesh
    side_ren.SetBackground(1, 1, 1)
    side_ren.SetViewport(0.87, 0, 1, 1)
    side_ren.AddActor2D(bar)
    ren.SetViewport(0, 0, 0.87, 1)
    if a.title:
        txt = vtk.vtkTextActor()
        txt.SetInput(a.title)
        txt.GetTextProperty().SetColor(0, 0, 0)
        txt.GetTextProperty().SetFontSize(20)
        txt.SetPosition(10, a.size[1] - 34)
        ren.AddActor2D(txt)

    # camera: looking at the plane along -normal, parallel projection framing the box
    b = a.box
    c = [(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2]
    d = sum((c[i] - a.point[i]) * n[i] for i in range(3))
    c = [c[i] - d * n[i] for i in range(3)]  # the box centre projected on the plane
    up = unit(a.up) if a.up else ([0, 0, 1] if abs(n[2]) < 0.9 else [0, 1, 0])
    diag = math.sqrt((b[1] - b[0]) ** 2 + (b[3] - b[2]) ** 2 + (b[5] - b[4]) ** 2)
    cam = ren.GetActiveCamera()
    cam.SetFocalPoint(*c)
    cam.SetPosition(*[c[i] + 2 * diag * n[i] for i in range(3)])
    cam.SetViewUp(*up)
    cam.ParallelProjectionOn()
    # half the picture's height: the box's extent along `up`, or its width along the other in-plane
    # direction divided by the aspect ratio, whichever is larger
    side = [n[1] * up[2] - n[2] * up[1], n[2] * up[0] - n[0] * up[2], n[0] * up[1] - n[1] * up[0]]
    corners = [(x, y, z) for x in b[0:2] for y in b[2:4] for z in b[4:6]]
    ext_up = max(abs(sum((p[i] - c[i]) * up[i] for i in range(3))) for p in corners)
    ext_side = max(abs(sum((p[i] - c[i]) * side[i] for i in range(3))) for p in corners)
    cam.SetParallelScale(1.02 * max(ext_up, ext_side * a.size[1] / (0.87 * a.size[0])))
    ren.ResetCameraClippingRange()

    rw = vtk.vtkRenderWindow()
    rw.SetOffScreenRendering(1)
    rw.AddRenderer(ren)
    rw.AddRenderer(side_ren)
    rw.SetSize(*a.size)
    rw.Render()
    shot = vtk.vtkWindowToImageFilter()
    shot.SetInput(rw)
    shot.Update()
    w = vtk.vtkPNGWriter()
    w.SetFileName(a.png)
    w.SetInputConnection(shot.GetOutputPort())
    w.Write()
    print("render-cut: %s: %d cells drawn -> %s" % (a.vtu, cells.GetNumberOfCells(), a.png))


if __name__ == "__main__":
    main()
