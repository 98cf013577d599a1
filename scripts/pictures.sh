#!/usr/bin/env bash
# Renders the README's pictures of the curved boundary layer (docs/img/*.png) from the VTU
# meshes of the demo and of the paper's STEP wing, headless (scripts/render-cut.py starts its own
# virtual X server when there is no DISPLAY).
# Usage: scripts/pictures.sh [BUILD]   (make pictures)
#        RENDER_ONLY=1 scripts/pictures.sh   renders from the existing out/*/mesh.vtu
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
if [ -z "${RENDER_ONLY:-}" ]; then
  "$build/meshflow" run workflows/naca_wingtip.yaml
  "$build/meshflow" run workflows/wingtip_step.yaml
  "$build/meshflow" run workflows/wing_body_parametric.yaml
  "$build/meshflow" run workflows/wing_body.yaml  # DLR-F6, ~2 min
  "$build/meshflow" run workflows/rotor67.yaml  # ~20 min on 2 cores, most of it optimise's untangling
fi
mkdir -p docs/img
render() { /usr/bin/python3 scripts/render-cut.py "$@"; }
# Both wings: chord along x, thickness y, span z from the wall z = 0, nose up. The places are
# fractions of each mesh's boundary-layer bounding box (--relative), so one set serves both
# (the demo is in chords, the STEP wing in mm).
le=(--relative --point 0 0 0.48 --normal 0 0 1 --box -0.05 0.16 0.4 1.08 0 1 --up 0 1 0)
tip=(--relative --point 0.32 0 0 --normal 1 0 0 --box 0.23 0.42 0.24 1.24 0.81 1.05 --up 0 1 0)
root=(--relative --point 0 0 0.001 --normal 0 0 -1 --box -0.03 0.32 0.34 1.14 0 0.29 --up 0 1 0)
for w in naca:naca-wingtip:"make demo" step:wingtip-step:"wingtip_step.yaml"; do
  IFS=: read -r tag name label <<<"$w"
  v=${VTU_DIR:-out}/$name/mesh.vtu
  render "$v" docs/img/${tag}_leading_edge.png "${le[@]}" --title "$label: leading edge at mid-span (cut normal to the span), order 4, 10 layers"
  render "$v" docs/img/${tag}_tip.png "${tip[@]}" --title "$label: the rounded tip (cut at 32 % of the chord)"
  render "$v" docs/img/${tag}_root.png "${root[@]}" --title "$label: the root seen through the wall: junction hexes around the leading edge"
done
# the parametric wing-body (body along x, wing along y, z up): the wall-wall junction block split
# 10 x 10, in a cut normal to the body axis at 30 % of the root chord (absolute coordinates)
render ${VTU_DIR:-out}/wing-body-parametric/mesh.vtu docs/img/wing_body_junction.png --point 27.3 0 0 --normal 1 0 0 \
  --box 27.1 27.3 2.86 3.38 -0.6 -0.2 --up 0 0 1 \
  --title "wing-body junction cut at x = 27.3: body left, wing below; order 4, 10 x 10 layers"
# DLR-F6 (mm; body along x, wing along -y, z up): a cut normal to the body through the
# wing-fuselage junction near the trailing edge of the root (the wing's upper and lower junction
# blocks, 10 x 10), and one through the wing tip (absolute coordinates)
render ${VTU_DIR:-out}/wing-body/mesh.vtu docs/img/dlr_f6_junction.png --point 215.6 0 0 --normal 1 0 0 \
  --box 214 217 -76 -52 -22 -2 --up 0 0 1 \
  --title "DLR-F6: wing-fuselage junction under the wing (cut x = 215.6 mm), order 4, 10 x 10 layers"
render ${VTU_DIR:-out}/wing-body/mesh.vtu docs/img/dlr_f6_tip.png --point 330 0 0 --normal 1 0 0 \
  --box 328 332 -592 -572 44 60 --up 0 0 1 \
  --title "DLR-F6: the wing tip (cut x = 330 mm), order 4, 10 layers"
# Rotor 67 (axis x, feet): cuts normal to the axis through the hub junction just behind the blade's
# leading edge and through the casing junction at the tip, radius (y) up (absolute coordinates)
render ${VTU_DIR:-out}/rotor67/mesh.vtu docs/img/rotor67_hub.png --point 0 0 0 --normal -1 0 0 \
  --box -0.005 0.005 0.305 0.34 -0.03 0.02 --up 0 1 0 \
  --title "Rotor 67: hub junction behind the blade's leading edge (cut x = 0), order 4, 10 layers"
render ${VTU_DIR:-out}/rotor67/mesh.vtu docs/img/rotor67_tip.png --point 0.08 0 0 --normal -1 0 0 \
  --box 0.075 0.085 0.80 0.85 -0.04 0.03 --up 0 1 0 \
  --title "Rotor 67: casing junction at the blade tip (cut x = 0.08 ft), order 4, 10 layers"
ls -la docs/img
