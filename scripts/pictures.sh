#!/usr/bin/env bash
# Renders the README's pictures of the curved boundary layer (docs/img/*.png) from the VTU
# meshes of the demo and of the paper's STEP wing, headless (VTK in a virtual X display).
# Usage: scripts/pictures.sh [BUILD]   (make pictures)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
"$build/meshflow" run workflows/naca_wingtip.yaml
"$build/meshflow" run workflows/wingtip_step.yaml
mkdir -p docs/img
render() { xvfb-run -a /usr/bin/python3 scripts/render-cut.py "$@"; }
n=out/naca-wingtip/mesh.vtu
s=out/wingtip-step/mesh.vtu
# the demo (NACA 0012, chord 1 along x, thickness y, span z from the root wall z = 0)
render $n docs/img/naca_leading_edge.png --point 0 0 0.5 --normal 0 0 1 --box -0.1 0.12 -0.1 0.1 0 1 --up 0 1 0 \
  --title "make demo: leading edge at mid-span (cut z = 0.5), order 4, 10 layers"
render $n docs/img/naca_root.png --point 0 0 0.001 --normal 0 0 -1 --box -0.08 0.3 -0.12 0.12 0 0.3 --up 0 1 0 \
  --title "make demo: the root, seen through the wall z = 0: junction hexes around the leading edge"
render $n docs/img/naca_tip.png --point 0.3 0 0 --normal 1 0 0 --box 0.2 0.4 -0.15 0.15 0.85 1.1 --up 0 1 0 \
  --title "make demo: rounded tip (cut x = 0.3)"
# the paper's wing (mm; chord along x from 170, thickness y, span z from the tunnel wall z = 0 to 916)
render $s docs/img/step_leading_edge.png --point 0 0 450 --normal 0 0 1 --box 110 430 250 510 0 916 --up 0 1 0 \
  --title "wingtip_step.yaml: leading edge (cut z = 450 mm)"
render $s docs/img/step_tip.png --point 500 0 0 --normal 1 0 0 --box 400 600 150 480 760 1000 --up 0 1 0 \
  --title "wingtip_step.yaml: rounded tip (cut x = 500 mm)"
ls -la docs/img
