#!/usr/bin/python3
"""Renders a cut through a meshflow VTU (VTK Lagrange cells, any order) into a PNG, headless.

The 3D cells inside a box that lie behind a plane (or cross it) are kept whole, so the picture
shows the elements' own curved faces at the cut, the way ParaView's "Extract Cells By Region"
does: faces tessellated finely (VTK's nonlinear subdivision, so their curvature shows), coloured
by the `scaled_jacobian` cell data meshflow writes, with every element edge drawn as a curve
(sampled from the cell's own Lagrange interpolation). The camera looks at the plane from its
front side (along -normal), parallel projection, framing the box.

Coordinates: by default --point and --box are in the mesh's units. With --relative they are
fractions of the "frame", the bounding box of the boundary layer (the VTU's prisms and hexahedra;
all 3D cells if it has none): 0 and 1 are the frame's faces on each axis, so one set of options
frames the same place (e.g. the wing-wall junction) on meshes of different size or units.
Without --box the picture frames the whole frame, 5 % larger.

Headless: VTK 9.1 from Debian (python3-vtk9) renders through X even off screen. Without a
DISPLAY the script starts its own virtual X server (Debian package xvfb, `Xvfb -displayfd`) and
stops it when done; `xvfb-run -a render-cut.py ...` works as well.

Examples (the demo, out/naca-wingtip/mesh.vtu, chord along x, span along z from the wall z = 0):
  the junction, a cut at 30 % chord through the layers at the wall:
    render-cut.py mesh.vtu junction.png --relative --point 0.3 0 0 --normal 1 0 0 \\
        --box 0.15 0.45 -0.3 1.3 -0.02 0.12 --up 0 1 0
  absolute coordinates, the leading edge at mid-span:
    render-cut.py mesh.vtu le.png --point 0 0 0.5 --normal 0 0 1 --box -0.1 0.12 -0.1 0.1 0 1 --up 0 1 0
"""
import argparse
import math
import os
import shutil
import subprocess
import sys

LAYER_CELL_TYPES = (72, 73, 12, 13)  # VTK Lagrange hexahedron, wedge; linear hexahedron, wedge


def parse():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("vtu", help="a VTU written by meshflow (out/<name>/mesh.vtu, or `meshflow convert X.msh X.vtu`)")
    p.add_argument("png", help="the picture to write")
    p.add_argument("--point", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="a point of the cut plane (default: the frame's centre)")
    p.add_argument("--normal", type=float, nargs=3, default=[0.0, 0.0, 1.0], metavar=("NX", "NY", "NZ"),
                   help="the plane's normal: cells wholly in front of the plane (on the normal's side) are removed, "
                        "the camera looks along -normal (default 0 0 1)")
    p.add_argument("--box", type=float, nargs=6, default=None, metavar=("X0", "X1", "Y0", "Y1", "Z0", "Z1"),
                   help="only cells inside or crossing this box are drawn; the picture frames it "
                        "(default: the frame, 5 %% larger)")
    p.add_argument("--relative", action="store_true",
                   help="--point and --box are fractions of the frame (the boundary layer's bounding box), not mesh units")
    p.add_argument("--up", type=float, nargs=3, default=None, metavar=("UX", "UY", "UZ"),
                   help="the picture's up direction (default: z, or y when the normal is along z)")
    p.add_argument("--size", type=int, nargs=2, default=[1200, 800], metavar=("W", "H"), help="picture size in pixels")
    p.add_argument("--subdivision", type=int, default=3,
                   help="tessellation level of curved faces (VTK nonlinear subdivision, >= 1; default 3)")
    p.add_argument("--edge-samples", type=int, default=8, help="segments per drawn element edge (default 8)")
    p.add_argument("--title", default="", help="text drawn in the top-left corner")
    p.add_argument("--no-edges", action="store_true", help="do not draw element edges")
    a = p.parse_args()
    if a.size[0] < 16 or a.size[1] < 16:
        p.error("--size must be at least 16 x 16 pixels")
    if a.subdivision < 1:
        p.error("--subdivision must be at least 1 (0 would draw curved faces as flat triangles)")
    if a.edge_samples < 1:
        p.error("--edge-samples must be at least 1")
    if a.box and (a.box[0] >= a.box[1] or a.box[2] >= a.box[3] or a.box[4] >= a.box[5]):
        p.error("--box X0 X1 Y0 Y1 Z0 Z1 needs X0 < X1, Y0 < Y1, Z0 < Z1")
    return a


def fail(msg):
    sys.exit("render-cut: " + msg)


def unit(v, what):
    n = math.sqrt(sum(c * c for c in v))
    if n == 0:
        fail("%s is the zero vector" % what)
    return [c / n for c in v]


class VirtualDisplay:
    """An Xvfb of our own when there is no DISPLAY (VTK 9.1 on Debian needs an X server even for
    off-screen rendering: its only render window is vtkXOpenGLRenderWindow)."""

    def __init__(self):
        self.proc = None
        if os.environ.get("DISPLAY"):
            return
        exe = shutil.which("Xvfb")
        if not exe:
            fail("no DISPLAY and no Xvfb: install Debian's xvfb (scripts/install-deps does) or run under an X server")
        r, w = os.pipe()
        # -displayfd: the server picks a free display number and writes it to w once it accepts clients
        self.proc = subprocess.Popen([exe, "-displayfd", str(w), "-nolisten", "tcp", "-screen", "0", "1920x1200x24"],
                                     pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(w)
        buf = b""
        while not buf.endswith(b"\n"):
            chunk = os.read(r, 32)
            if not chunk:
                break
            buf += chunk
        os.close(r)
        if not buf.strip().isdigit():
            self.close()
            fail("Xvfb did not start (no display number from -displayfd)")
        os.environ["DISPLAY"] = ":" + buf.decode().strip()

    def close(self):
        if self.proc:
            self.proc.terminate()
            self.proc.wait()
            self.proc = None


def curved_edges(vtk, surface_cells, samples):
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


def volume_cells(vtk, grid):
    """The 3D cells (the VTU's boundary triangles/quads/lines would hide the cut)."""
    if grid.GetCellData().GetArray("entity_dim") is None:
        return grid
    th = vtk.vtkThreshold()
    th.SetInputData(grid)
    th.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_CELLS, "entity_dim")
    th.SetLowerThreshold(3)
    th.SetUpperThreshold(3)
    th.Update()
    return th.GetOutput()


def frame_bounds(vol):
    """Bounding box of the boundary layer (prism and hex cells), else of every cell."""
    lo, hi = [math.inf] * 3, [-math.inf] * 3
    b = [0.0] * 6
    for i in range(vol.GetNumberOfCells()):
        if vol.GetCellType(i) in LAYER_CELL_TYPES:
            vol.GetCellBounds(i, b)
            for k in range(3):
                lo[k] = min(lo[k], b[2 * k])
                hi[k] = max(hi[k], b[2 * k + 1])
    if lo[0] > hi[0]:
        b = vol.GetBounds()
        lo, hi = [b[0], b[2], b[4]], [b[1], b[3], b[5]]
    return lo, hi


def render(vtk, a):
    rd = vtk.vtkXMLUnstructuredGridReader()
    rd.SetFileName(a.vtu)
    rd.Update()
    grid = rd.GetOutput()
    if grid.GetNumberOfCells() == 0:
        fail("%s has no cells (is it a VTU file?)" % a.vtu)
    vol = volume_cells(vtk, grid)
    if vol.GetNumberOfCells() == 0:
        fail("%s has no 3D cells" % a.vtu)

    lo, hi = frame_bounds(vol)
    ext = [max(hi[k] - lo[k], 1e-300) for k in range(3)]
    if a.relative:
        point = [lo[k] + a.point[k] * ext[k] for k in range(3)] if a.point else None
        box = [lo[k // 2] + a.box[k] * ext[k // 2] for k in range(6)] if a.box else None
    else:
        point, box = a.point, a.box
    if box is None:
        box = [v for k in range(3) for v in (lo[k] - 0.05 * ext[k], hi[k] + 0.05 * ext[k])]
    if point is None:
        point = [(lo[k] + hi[k]) / 2 for k in range(3)]
    n = unit(a.normal, "--normal")

    vbox = vtk.vtkBox()
    vbox.SetBounds(*box)
    in_box = vtk.vtkExtractGeometry()
    in_box.SetInputData(vol)
    in_box.SetImplicitFunction(vbox)
    in_box.ExtractInsideOn()
    in_box.ExtractBoundaryCellsOn()
    plane = vtk.vtkPlane()
    plane.SetOrigin(*point)
    plane.SetNormal(*n)
    behind = vtk.vtkExtractGeometry()  # whole cells, so their curved faces and edges show at the cut
    behind.SetInputConnection(in_box.GetOutputPort())
    behind.SetImplicitFunction(plane)
    behind.ExtractInsideOn()  # f(x) = n . (x - p) < 0
    behind.ExtractBoundaryCellsOn()
    behind.Update()
    cells = behind.GetOutput()
    if cells.GetNumberOfCells() == 0:
        fail("no cell of %s lies in the box behind the plane: check --box, --point, --normal "
             "(the frame, the boundary layer's bounds, is x %.6g..%.6g, y %.6g..%.6g, z %.6g..%.6g)"
             % (a.vtu, lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))

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
    if cells.GetCellData().GetArray("scaled_jacobian") is None:
        m.ScalarVisibilityOff()
        faces.GetProperty().SetColor(0.8, 0.8, 0.8)

    ren = vtk.vtkRenderer()
    ren.SetBackground(1, 1, 1)
    ren.AddActor(faces)
    if not a.no_edges:
        geo = vtk.vtkUnstructuredGridGeometryFilter()  # the surface as higher-order 2D cells
        geo.SetInputData(cells)
        geo.Update()
        em = vtk.vtkPolyDataMapper()
        em.SetInputData(curved_edges(vtk, geo.GetOutput(), a.edge_samples))
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
        tp = txt.GetTextProperty()
        tp.SetColor(0, 0, 0)
        tp.SetFontSize(max(10, min(20, a.size[1] // 40)))
        tp.SetBackgroundColor(1, 1, 1)  # readable over the mesh
        tp.SetBackgroundOpacity(0.85)
        tp.SetVerticalJustificationToTop()
        txt.SetPosition(8, a.size[1] - 8)
        ren.AddActor2D(txt)

    # camera: looking at the plane along -normal, parallel projection framing the box
    b = box
    c = [(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2]
    d = sum((c[i] - point[i]) * n[i] for i in range(3))
    c = [c[i] - d * n[i] for i in range(3)]  # the box centre projected on the plane
    up = unit(a.up, "--up") if a.up else ([0, 0, 1] if abs(n[2]) < 0.9 else [0, 1, 0])
    dot = sum(up[i] * n[i] for i in range(3))
    up = [up[i] - dot * n[i] for i in range(3)]  # in the picture's plane
    if math.sqrt(sum(u * u for u in up)) < 1e-6:
        fail("--up is parallel to --normal")
    up = unit(up, "--up")
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
    # the camera stands 2 box diagonals in front of the plane: the clipping range must hold the
    # whole box (ResetCameraClippingRange alone would clip the cells behind the plane at times)
    cam.SetClippingRange(0.5 * diag, 4 * diag)

    rw = vtk.vtkRenderWindow()
    rw.SetOffScreenRendering(1)
    rw.AddRenderer(ren)
    rw.AddRenderer(side_ren)
    rw.SetSize(*a.size)
    rw.Render()
    shot = vtk.vtkWindowToImageFilter()
    shot.SetInput(rw)
    shot.ReadFrontBufferOff()
    shot.Update()
    w = vtk.vtkPNGWriter()
    w.SetFileName(a.png)
    w.SetInputConnection(shot.GetOutputPort())
    w.Write()
    rw.Finalize()  # close the X connection before a virtual display of ours goes away
    sj = cells.GetCellData().GetArray("scaled_jacobian")
    sj_min = sj.GetRange()[0] if sj is not None else float("nan")
    print("render-cut: %s: frame x %.6g..%.6g, y %.6g..%.6g, z %.6g..%.6g; %d cells drawn (min scaled Jacobian %.3g) -> %s"
          % (a.vtu, lo[0], hi[0], lo[1], hi[1], lo[2], hi[2], cells.GetNumberOfCells(), sj_min, a.png))


def main():
    a = parse()
    try:
        import vtk
    except ImportError as e:
        fail("cannot import vtk (%s): install Debian's python3-vtk9 and run with /usr/bin/python3" % e)
    display = VirtualDisplay()
    try:
        render(vtk, a)
    finally:
        display.close()


if __name__ == "__main__":
    main()
