# Install rules and the Debian package (CPack). `cmake --install BUILD --prefix P` (or
# `make install PREFIX=P`) puts:
#   P/bin/meshflow                              the program (its schemas are built into it)
#   P/share/meshflow/schemas/*.json             the JSON schemas, for editors (workflow-editor.json)
#   P/share/doc/meshflow/                       README.md, LICENSE, CHANGELOG.md, SOURCES.md, docs/
#   P/share/doc/meshflow/examples/              the demo workflow and the paper's wing STEP file
# `make package` (cpack -G DEB in the build folder) makes meshflow_<version>_<arch>.deb installed
# under /usr, with the Debian 12 runtime packages of every library the program links declared as
# dependencies (tests/package/package_test.sh checks the list against the binary's NEEDED entries).
include(GNUInstallDirs)

# `install` installs what was built: the Makefile's install and package targets build first, and
# the package test must not relink the program other tests are running.
set(CMAKE_SKIP_INSTALL_ALL_DEPENDENCY ON)

install(TARGETS meshflow RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
install(DIRECTORY ${PROJECT_SOURCE_DIR}/schemas/ DESTINATION ${CMAKE_INSTALL_DATADIR}/meshflow/schemas
        FILES_MATCHING PATTERN "*.json")
install(FILES ${PROJECT_SOURCE_DIR}/README.md ${PROJECT_SOURCE_DIR}/LICENSE ${PROJECT_SOURCE_DIR}/CHANGELOG.md
              ${PROJECT_SOURCE_DIR}/SOURCES.md
        DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(DIRECTORY ${PROJECT_SOURCE_DIR}/docs/ DESTINATION ${CMAKE_INSTALL_DOCDIR}/docs)
install(FILES ${PROJECT_SOURCE_DIR}/workflows/naca_wingtip.yaml ${PROJECT_SOURCE_DIR}/data/wingtip/3d_bl_wing.stp
        DESTINATION ${CMAKE_INSTALL_DOCDIR}/examples)

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME meshflow)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "valid high-order curvilinear hybrid meshes for CFD, from CAD")
set(CPACK_PACKAGE_DESCRIPTION "meshflow turns CAD (STEP, IGES, BREP) into high-order curvilinear hybrid meshes:
stretched prisms and hexahedra in the boundary layer, tetrahedra in the far field, order 4 by
default, each proven valid over its whole element. A workflow file declares the stages; a
content-addressed cache runs only what changed. Writes Gmsh MSH, VTK, Nektar++ XML and CGNS.")
set(CPACK_PACKAGE_CONTACT "meshflow developers <meshflow@localhost>")
set(CPACK_RESOURCE_FILE_LICENSE ${PROJECT_SOURCE_DIR}/LICENSE)
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_STRIP_FILES ON)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_LICENSE "GPL-3.0-or-later")
# The Debian 12 packages of the shared libraries the program links (objdump -p meshflow | grep
# NEEDED, then dpkg -S): OpenCASCADE 7.6, TetGen 1.5, COLAMD and GMP (lp_solve, CGAL), CGNS,
# yaml-cpp, OpenSSL, curl, oneTBB, expat, zlib, the C and C++ runtimes.
set(CPACK_DEBIAN_PACKAGE_DEPENDS
    "libocct-foundation-7.6, libocct-modeling-data-7.6, libocct-modeling-algorithms-7.6, libocct-data-exchange-7.6, libtet1.5, libcolamd2, libgmp10, libcgns3.4, libyaml-cpp0.7, libssl3, libcurl4, libtbb12, libexpat1, zlib1g, libstdc++6, libgcc-s1, libc6")
include(CPack)
