# Writes data/cad-defects/hemisph-cyl.stp: meshflow's own stand-in for the UGAWG hemisphere-cylinder
# half domain (whose file states no licence and is not shipped). The same shape and defect class:
# a fluid solid of 5 faces (far-field sphere R 100 about (10, 0, 0) cut at x = 10 and y = 0, minus a
# cylinder R 0.5 from x = 0.5 to 10 with a hemispherical nose), whose two spheres have their poles
# on the solid's boundary, so OCCT imports it with 4 degenerated edges and sewing reports 4
# degenerated shapes, as for the UGAWG file. Run with Debian's gmsh module:
#   /usr/bin/python3 data/cad-defects/hemisph_cyl.py data/cad-defects/hemisph-cyl.stp
import sys

import gmsh

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
occ = gmsh.model.occ
far = occ.addSphere(10, 0, 0, 100)
half = occ.addBox(-90, 0, -100, 100, 100, 200)  # x <= 10, y >= 0
domain, _ = occ.intersect([(3, far)], [(3, half)])
cylinder = occ.addCylinder(0.5, 0, 0, 9.5, 0, 0, 0.5)
nose = occ.addSphere(0.5, 0, 0, 0.5)
body, _ = occ.fuse([(3, cylinder)], [(3, nose)])
occ.cut(domain, body)
occ.synchronize()
gmsh.write(sys.argv[1])
gmsh.finalize()
