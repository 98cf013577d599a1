#!/usr/bin/env python3
"""Random CAD for meshflow's corpus: N STEP solids in metres from a seed, built on Gmsh's
OpenCASCADE API (Debian's python3-gmsh, Gmsh 4.8; run with /usr/bin/python3).

    /usr/bin/python3 scripts/random-cad.py --seed S --n N --out DIR [--families a,b] [--only I,J]
    /usr/bin/python3 scripts/random-cad.py --check DIR

Writes DIR/rand_S_III_<family>.step for shape III = 0 .. N-1 and DIR/shapes.json listing each
file with its family, every random value drawn (so a failing shape can be described and re-made)
and the attempts that failed. Shape i draws from random.Random(f"{S}-{i}") (its family) and
random.Random(f"{S}-{i}-{attempt}") (its parameters), so it does not depend on N. Existing
rand_S_*.step files in DIR are removed first (not with --only).

Families (uniform choice):
  wing           NACA 4/5-digit wing lofted root to tip (taper, sweep, twist, dihedral, sharp or
                 blunt trailing edge, flat or round tip), planar root face; a body alone
  half_wing      the same wing with its root face on the plane z = 0, span along +z (a half model)
  wing_body      body of revolution (elliptic nose, cylinder, tapered tail) with a wing pair fused
  propeller      2-6 twisted lofted blades on a cylindrical or spinner hub, fused
  revolved_body  spline profile revolved 360 degrees, with 0, 3 or 4 fins (boxes or lofted plates)
  duct           a fluid volume with planar open ends: bent pipe (pipe sweep or torus segment),
                 tee/Y junction, converging-diverging nozzle, rectangular duct with a bend
  block          box with pockets, holes and slots cut, then some edges filleted
  close_bodies   2 or 3 spheres/ellipsoids/boxes/cylinders with gaps of 2-10 % of their size

Every shape is checked before it is kept: the expected number of solids, each with a positive
volume, no loose faces, curves or points, characteristic length (largest bounding-box side)
0.5-3 m (a uniform scale about the origin brings it there, recorded as fit_scale), and the
written STEP re-imported in metres with the same solids, volumes and bounding box. An attempt
that fails (OCC error, crash, timeout or check) is re-drawn with the next sub-seed; the failures
are listed under "failed_attempts". `--check DIR` re-imports every file of DIR/shapes.json in a
fresh Gmsh and prints a summary.

Gmsh 4.8 cannot tell OCCT to write metres (Geometry.OCCTargetUnit only converts the numbers), so
the file is written with the model's numbers as they are and its length unit is set to metres in
the text; the timestamp in the header is fixed, so a seed gives byte-identical files.
"""
import argparse
import glob
import json
import math
import multiprocessing
import os
import random
import re
import sys
import time

import gmsh

FAMILIES = ["wing", "half_wing", "wing_body", "propeller", "revolved_body", "duct", "block",
            "close_bodies"]
MAX_ATTEMPTS = 6
ATTEMPT_TIMEOUT_S = 120
SIZE_RANGE = (0.5, 3.0)        # characteristic length (largest bounding-box side), metres
NACA_POINTS = 36               # control points per airfoil side
FIVE_DIGIT = {1: (0.0580, 361.4), 2: (0.1260, 51.64), 3: (0.2025, 15.957),
              4: (0.2900, 6.643), 5: (0.3910, 3.230)}    # NACA 5-digit camber: P -> (r, k1)


# ----------------------------------------------------------------------------------------------
# Recorded random draws

class Draw:
    """Random values that record themselves under their name in `params` (rounded to 6 decimals,
    and the rounded value is the one used, so the record re-makes the shape exactly)."""

    def __init__(self, rng, params):
        self.rng, self.params = rng, params

    def _put(self, name, value):
        if name in self.params:
            raise KeyError("parameter drawn twice: " + name)
        self.params[name] = value
        return value

    def uniform(self, name, lo, hi):
        return self._put(name, round(self.rng.uniform(lo, hi), 6))

    def integer(self, name, lo, hi):
        return self._put(name, self.rng.randint(lo, hi))

    def choice(self, name, options):
        return self._put(name, self.rng.choice(options))

    def chance(self, name, p):
        return self._put(name, self.rng.random() < p)

    def note(self, name, value):
        """A derived value (not drawn), recorded to describe the shape."""
        return self._put(name, round(value, 6) if isinstance(value, float) else value)

    def sub(self, name):
        return Draw(self.rng, self._put(name, {}))

    def item(self, name):
        """A new entry of the list `name`."""
        entry = {}
        self.params.setdefault(name, []).append(entry)
        return Draw(self.rng, entry)


# ----------------------------------------------------------------------------------------------
# Small geometry helpers

def occ():
    return gmsh.model.occ


def volumes(dim_tags):
    return [t for d, t in dim_tags if d == 3]


def one_volume(dim_tags, what):
    v = volumes(dim_tags)
    if len(v) != 1:
        raise RuntimeError("%s gave %d solids, expected 1" % (what, len(v)))
    return v[0]


def fuse_all(first, others, what):
    """Fuse volume `first` with the volumes `others`; one solid expected."""
    out, _ = occ().fuse([(3, first)], [(3, t) for t in others])
    return one_volume(out, what)


def unit(v):
    n = math.sqrt(sum(c * c for c in v))
    return [c / n for c in v]


def profile_samples(curve, n=200):
    """(x, y) points along a curve of the x-y plane (model synchronised first)."""
    occ().synchronize()
    lo, hi = gmsh.model.getParametrizationBounds(1, curve)
    ts = [lo[0] + (hi[0] - lo[0]) * k / (n - 1) for k in range(n)]
    xyz = gmsh.model.getValue(1, curve, ts)
    return [(xyz[3 * k], xyz[3 * k + 1]) for k in range(n)]


def check_profile(samples, x_end, what):
    """A revolved profile must stay off the axis between its ends and within its length."""
    inner = samples[2:-2]
    if min(y for _, y in inner) <= 1e-4 * x_end:
        raise RuntimeError(what + " profile touches the axis")
    if min(x for x, _ in samples) < -1e-3 * x_end or max(x for x, _ in samples) > x_end * (1 + 1e-3):
        raise RuntimeError(what + " profile overshoots its ends")


# ----------------------------------------------------------------------------------------------
# NACA sections and lofted wings

def draw_profile(d, t_range, camber_max, series=(4, 5)):
    """NACA 4-digit (m, p) or 5-digit (design lift digit L, camber position digit P) section and
    its thickness (t_range None: none drawn, the caller sets it per section); camber_max 0: a
    symmetric 4-digit section."""
    s = d.choice("series", list(series)) if camber_max > 0 else d.note("series", 4)
    if s == 4:
        symmetric = camber_max == 0 or d.chance("symmetric", 0.3)
        m = 0.0 if symmetric else d.uniform("m", 0.01, camber_max)
        p = d.uniform("p", 0.2, 0.6)
        t = d.uniform("t", *t_range) if t_range else None
        d.note("naca", "%d%d" % (round(m * 100), round(p * 10)) + ("%02d" % round(t * 100) if t else "xx"))
        return {"series": 4, "m": m, "p": p}, t
    lift = d.choice("L", [1, 2, 3])
    pos = d.choice("P", [1, 2, 3, 4, 5])
    t = d.uniform("t", *t_range) if t_range else None
    d.note("naca", "%d%d0" % (lift, pos) + ("%02d" % round(t * 100) if t else "xx"))
    return {"series": 5, "L": lift, "P": pos}, t


def camber(profile, x):
    """Mean line height and slope at x (unit chord)."""
    if profile["series"] == 4:
        m, p = profile["m"], profile["p"]
        if m == 0:
            return 0.0, 0.0
        if x < p:
            return m / p**2 * (2 * p * x - x * x), 2 * m / p**2 * (p - x)
        return m / (1 - p)**2 * (1 - 2 * p + 2 * p * x - x * x), 2 * m / (1 - p)**2 * (p - x)
    r, k1 = FIVE_DIGIT[profile["P"]]
    k1 *= 0.15 * profile["L"] / 0.3
    if x < r:
        return (k1 / 6 * (x**3 - 3 * r * x * x + r * r * (3 - r) * x),
                k1 / 6 * (3 * x * x - 6 * r * x + r * r * (3 - r)))
    return k1 * r**3 / 6 * (1 - x), -k1 * r**3 / 6


def airfoil(profile, t, camber_scale, te_thickness):
    """Upper and lower control polygons of a unit-chord section, leading edge first.
    te_thickness 0: sharp (closed) trailing edge; else its total thickness (chord fraction).
    A point on the leading-edge normal after the nose makes both sides leave it in one tangent."""
    n = NACA_POINTS - 2
    upper, lower = [], []
    for j in range(n + 1):
        x = 0.5 * (1 - math.cos(math.pi * j / n))
        yt = 5 * t * (0.2969 * math.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3
                      - 0.1036 * x**4) + 0.5 * te_thickness * x
        if j == n and te_thickness == 0:
            yt = 0.0
        yc, slope = camber(profile, x)
        th = math.atan(camber_scale * slope)
        yc *= camber_scale
        upper.append((x - yt * math.sin(th), yc + yt * math.cos(th)))
        lower.append((x + yt * math.sin(th), yc - yt * math.cos(th)))
    th0 = math.atan(camber_scale * camber(profile, 0.0)[1])
    eps = 0.5 * math.hypot(*upper[1])
    upper.insert(1, (-eps * math.sin(th0), eps * math.cos(th0)))
    lower.insert(1, (eps * math.sin(th0), -eps * math.cos(th0)))
    return upper, lower


def section_point(p, sec, pivot):
    """Section coordinates -> wing frame (x chordwise, y up, z span): scale by the chord, twist
    nose-up about the pivot, offset to the section's leading-edge x and height y."""
    c, tau = sec["chord"], math.radians(sec["twist_deg"])
    xr, yr = (p[0] - pivot) * c, p[1] * c
    return (sec["x_le"] + pivot * c + xr * math.cos(tau) + yr * math.sin(tau),
            sec["y"] - xr * math.sin(tau) + yr * math.cos(tau),
            sec["z"])


def loft_wing(wing):
    """Solid lofted (ThruSections) through the sections of `wing`, in planes z = const, closed
    by planar root and tip faces; a round tip is a cap revolved about the tip chord and fused.
    wing: profile, pivot, te_thickness, tip, sections [{z, chord, twist_deg, x_le, y, t, camber}]."""
    o = occ()
    blunt = wing["te_thickness"] > 0
    wires, tip = [], None
    for sec in wing["sections"]:
        upper, lower = airfoil(wing["profile"], sec["t"], sec["camber"], wing["te_thickness"])
        pts = [section_point(p, sec, wing["pivot"]) for p in upper]
        lpts = [section_point(p, sec, wing["pivot"]) for p in lower]
        le = o.addPoint(*pts[0])
        te_u = o.addPoint(*pts[-1])
        te_l = o.addPoint(*lpts[-1]) if blunt else te_u
        c_up = o.addBSpline([te_u] + [o.addPoint(*p) for p in reversed(pts[1:-1])] + [le])
        c_lo = o.addBSpline([le] + [o.addPoint(*p) for p in lpts[1:-1]] + [te_l])
        curves = [c_up, c_lo] + ([o.addLine(te_l, te_u)] if blunt else [])
        wires.append(o.addWire(curves, checkClosed=True))
        te_mid = [(a + b) / 2 for a, b in zip(pts[-1], lpts[-1])]
        tip = {"c_up": c_up, "le": le, "te_u": te_u, "le_xyz": pts[0], "te_mid": te_mid}
    vol = one_volume(o.addThruSections(wires, makeSolid=True, makeRuled=False), "loft")
    if wing["tip"] == "round":
        # The tip section is symmetric (camber washed out): revolving its upper half 180 degrees
        # about the chord line, upper side outward, gives a cap whose end faces fill the tip face.
        mid = o.addPoint(*tip["te_mid"]) if blunt else tip["te_u"]
        loop = [tip["c_up"], o.addLine(tip["le"], mid)] + ([o.addLine(mid, tip["te_u"])] if blunt else [])
        half = o.addPlaneSurface([o.addCurveLoop(loop)])
        axis = [b - a for a, b in zip(tip["le_xyz"], tip["te_mid"])]
        cap = one_volume(o.revolve([(2, half)], *tip["le_xyz"], *axis, math.pi), "tip cap")
        vol = fuse_all(vol, [cap], "round tip")
    return vol


def draw_trailing_edge(d):
    if d.choice("trailing_edge", ["sharp", "blunt"]) == "blunt":
        return d.uniform("te_thickness", 0.003, 0.012)
    return 0.0


def draw_planform(d, thickness, min_thickness):
    """Taper, sweep, twist, dihedral, section (profile, thickness), trailing edge and tip of a
    wing, drawn in this order (the order is part of a seed's shapes)."""
    taper = d.uniform("taper", 0.3, 1.0)
    sweep = d.uniform("sweep_le_deg", 0.0, 40.0)
    twist = d.uniform("tip_twist_deg", -5.0, 3.0)
    dihedral = d.uniform("dihedral_deg", 0.0, 8.0)
    profile, t = draw_profile(d.sub("section"), thickness, min_thickness)
    te = draw_trailing_edge(d)
    tip = d.choice("tip", ["flat", "round"])
    d.note("camber_washout", tip == "round")     # a round tip needs a symmetric tip section
    return taper, sweep, twist, dihedral, profile, t, te, tip


def draw_wing(d, semi_span, z_root=0.0):
    """A straight-tapered wing planform from z_root to the tip at semi_span (sections in wing frame)."""
    ar = d.uniform("semi_aspect_ratio", 1.2, 4.0)          # semi-span / root chord
    c_root = d.note("root_chord", semi_span / ar)
    taper, sweep, twist, dihedral, profile, t, te, tip = draw_planform(d, (0.08, 0.18), 0.06)
    sections = []
    for z in (z_root, semi_span):
        s = z / semi_span
        sections.append({"z": z, "chord": c_root * (1 - (1 - taper) * s), "twist_deg": twist * s,
                         "x_le": z * math.tan(math.radians(sweep)),
                         "y": z * math.tan(math.radians(dihedral)), "t": t,
                         "camber": (1 - s) if tip == "round" else 1.0})
    return {"profile": profile, "pivot": 0.25, "te_thickness": te, "tip": tip, "sections": sections}


# ----------------------------------------------------------------------------------------------
# Bodies of revolution (about the x axis, profile in the x-y plane)

def revolve_profile(curves):
    """Solid of revolution about x of the planar face bounded by `curves`, as two 180-degree
    halves fused. (OCCT 7.6's STEP round trip loses the trimming of a single 360-degree face with
    two poles once a fin root cuts a hole in it; two half faces come back intact.)"""
    o = occ()
    face = o.addPlaneSurface([o.addCurveLoop(curves)])
    half = one_volume(o.revolve([(2, face)], 0, 0, 0, 1, 0, 0, math.pi), "revolve")
    other = o.copy([(3, half)])
    o.rotate(other, 0, 0, 0, 1, 0, 0, math.pi)
    return fuse_all(half, volumes(other), "revolve halves")


def fuselage(length, radius, nose, tail, tail_radius):
    """Elliptic nose of length `nose`, cylinder, straight tapered tail of length `tail` ending in
    a flat base of `tail_radius` (or a point when 0). The nose quarter ellipse is an exact
    rational quadratic B-spline (OCCT 7.6 reads a surface of revolution of an ELLIPSE back from
    STEP with the wrong extent) and the straight wall segments are degree-1 B-splines (the two
    halves' cones, from lines, meeting at the tail apex make OCCT's fuse throw)."""
    o = occ()
    p_nose, p_corner = o.addPoint(0, 0, 0), o.addPoint(0, radius, 0)
    p_a, p_b = o.addPoint(nose, radius, 0), o.addPoint(length - tail, radius, 0)
    p_end = o.addPoint(length, 0, 0)
    curves = [o.addBSpline([p_a, p_corner, p_nose], degree=2, weights=[1, math.sqrt(0.5), 1]),
              o.addBSpline([p_a, p_b], degree=1)]
    if tail_radius > 0:
        p_base = o.addPoint(length, tail_radius, 0)
        curves += [o.addBSpline([p_b, p_base], degree=1), o.addLine(p_base, p_end)]
    else:
        curves += [o.addBSpline([p_b, p_end], degree=1)]
    curves.append(o.addLine(p_end, p_nose))
    return revolve_profile(curves)


# ----------------------------------------------------------------------------------------------
# Families. Each builds its shape in the current model and returns how many solids it made and
# how it may be moved: "free" (any rigid motion), "plane" (stay on z = 0: shifts in x, y only).

def family_wing(d):
    """A wing alone: lofted NACA wing with planar root and tip faces (or round tip)."""
    semi_span = d.uniform("semi_span", 0.5, 2.5)
    loft_wing(draw_wing(d.sub("wing"), semi_span))
    return 1, "free"


def family_half_wing(d):
    """The wing with its root face on z = 0 and the span along +z: a half model."""
    semi_span = d.uniform("semi_span", 0.5, 2.5)
    loft_wing(draw_wing(d.sub("wing"), semi_span))
    return 1, "plane"


def family_wing_body(d):
    """Fuselage along x (elliptic nose, cylinder, tapered tail) with a wing pair fused through it."""
    length = d.uniform("fuselage_length", 1.0, 3.0)
    radius = d.note("fuselage_radius", length / 2 / d.uniform("fineness", 4.0, 7.0))
    nose = d.note("nose_length", radius * d.uniform("nose_fineness", 1.0, 3.0))
    tail = d.note("tail_length", radius * d.uniform("tail_fineness", 2.0, 4.5))
    tail_radius = radius * d.choice("tail_end", [0.0, 0.15, 0.3])
    body = fuselage(length, radius, nose, tail, tail_radius)

    cyl = length - nose - tail                      # wing root chord within the cylinder
    w = d.sub("wing")
    semi_span = w.uniform("semi_span", 0.4 * length, 0.7 * length)
    c_root = w.note("root_chord", cyl * w.uniform("root_chord_of_cylinder", 0.45, 0.85))
    taper, sweep, twist, dihedral, profile, t, te, tip = draw_planform(w, (0.08, 0.16), 0.05)
    x_le = nose + (cyl - c_root) * w.uniform("root_position", 0.1, 0.9)
    z_wing = radius * w.uniform("height", -0.5, 0.5)           # low, mid or high wing
    z_wing = w.note("z_wing", max(-0.85 * radius + 0.7 * t * c_root,
                                  min(0.85 * radius - 0.7 * t * c_root, z_wing)))
    z0 = -0.1 * radius                                          # roots overlap inside the body
    sections = []
    for z in (z0, semi_span):
        s = max(z, 0.0) / semi_span
        sections.append({"z": z, "chord": c_root * (1 - (1 - taper) * s), "twist_deg": twist * s,
                         "x_le": z * math.tan(math.radians(sweep)),
                         "y": z * math.tan(math.radians(dihedral)), "t": t,
                         "camber": (1 - s) if tip == "round" else 1.0})
    left = loft_wing({"profile": profile, "pivot": 0.25, "te_thickness": te, "tip": tip,
                      "sections": sections})
    # wing frame (chord x, up y, span z) -> body frame (span -y, up +z), then mirror to +y
    occ().rotate([(3, left)], 0, 0, 0, 1, 0, 0, math.pi / 2)
    occ().translate([(3, left)], x_le, 0, z_wing)
    right = volumes(occ().copy([(3, left)]))[0]
    occ().mirror([(3, right)], 0, 1, 0, 0)
    fuse_all(body, [left, right], "wing-body fuse")
    return 1, "free"


def family_propeller(d):
    """N twisted lofted blades (pitch angle atan(P / 2 pi r)) on a cylinder or spinner hub, axis y."""
    n_blades = d.integer("blades", 2, 6)
    r_tip = d.uniform("tip_radius", 0.3, 1.5)
    r_hub = d.note("hub_radius", r_tip * d.uniform("hub_ratio", 0.12, 0.25))
    pitch = d.note("pitch", 2 * r_tip * d.uniform("pitch_ratio", 0.6, 1.4))
    c_max = r_tip * d.uniform("max_chord_ratio", 0.1, 0.25)
    xi_max = d.uniform("max_chord_position", 0.2, 0.6)
    c_tip = c_max * d.uniform("tip_chord_ratio", 0.3, 0.7)
    t_root = d.uniform("root_thickness", 0.12, 0.20)
    t_tip = d.uniform("tip_thickness", 0.05, 0.08)
    skew = d.uniform("skew_deg", 0.0, 20.0)
    profile, _ = draw_profile(d.sub("section"), None, 0.04, series=(4,))
    te = draw_trailing_edge(d)
    tip = d.choice("tip", ["flat", "round"])
    d.note("camber_washout", tip == "round")
    n_outer = d.integer("outer_sections", 3, 5)
    pivot = 0.35

    def beta(r):
        return math.degrees(math.atan(pitch / (2 * math.pi * r)))

    r0 = 0.5 * r_hub                                 # blade roots start inside the hub
    half = max(pivot, 1 - pivot)
    c_hub = c_max * d.uniform("hub_chord_ratio", 0.6, 0.9)
    c_hub = min(c_hub,
                0.7 * 2 * math.pi * r_hub / n_blades / math.cos(math.radians(beta(r_hub))),
                0.75 * r_hub / (half * math.cos(math.radians(beta(r0))) + 0.5 * t_root))
    d.note("hub_chord", c_hub)

    def chord(xi):
        if xi <= xi_max:
            return c_hub + (c_max - c_hub) * math.sin(0.5 * math.pi * xi / xi_max)
        return c_tip + (c_max - c_tip) * math.cos(0.5 * math.pi * (xi - xi_max) / (1 - xi_max))

    sections = []
    for r in [r0] + [r_hub + (r_tip - r_hub) * k / n_outer for k in range(n_outer + 1)]:
        xi = max(0.0, (r - r_hub) / (r_tip - r_hub))
        c = chord(xi)
        sections.append({"z": r, "chord": c, "twist_deg": beta(r),
                         "x_le": -pivot * c + max(0.0, r - r_hub) * math.tan(math.radians(skew)), "y": 0.0,
                         "t": t_root + (t_tip - t_root) * xi,
                         "camber": (1 - xi) if tip == "round" else 1.0})
    blade = loft_wing({"profile": profile, "pivot": pivot, "te_thickness": te, "tip": tip,
                       "sections": sections})
    axial = max(half * s["chord"] * math.sin(math.radians(s["twist_deg"])) + 0.5 * s["t"] * s["chord"]
                for s in sections[:2])
    hub_len = d.note("hub_length", max(r_hub * d.uniform("hub_length_ratio", 1.5, 4.0), 2.6 * axial))
    hub = occ().addCylinder(0, -hub_len / 2, 0, 0, hub_len, 0, r_hub)
    if d.choice("hub", ["cylinder", "spinner"]) == "spinner":
        nose = occ().addSphere(0, -hub_len / 2, 0, r_hub)
        occ().dilate([(3, nose)], 0, -hub_len / 2, 0, 1, d.uniform("spinner_fineness", 1.0, 2.5), 1)
        hub = fuse_all(hub, [nose], "spinner")
    blades = [blade]
    for k in range(1, n_blades):
        copy = volumes(occ().copy([(3, blade)]))[0]
        occ().rotate([(3, copy)], 0, 0, 0, 0, 1, 0, 2 * math.pi * k / n_blades)
        blades.append(copy)
    fuse_all(hub, blades, "propeller fuse")
    return 1, "free"


def family_revolved_body(d):
    """Spline profile through 5-8 radius points revolved about x; 0, 3 or 4 tail fins fused."""
    o = occ()
    length = d.uniform("length", 0.8, 3.0)
    r_max = d.note("max_radius", length / 2 / d.uniform("fineness", 3.0, 10.0))
    n = d.integer("points", 5, 8)
    nose = d.choice("nose", ["pointed", "round"])
    tail = d.choice("tail", ["pointed", "round", "base"])
    shape_a = d.uniform("shape_exponent", 0.3, 1.0)      # where the thickest point sits
    xs, rs = [], []
    for j in range(n):
        xi = j / (n - 1)
        if 0 < j < n - 1:
            xi += d.uniform("dx%d" % j, -0.25, 0.25) / (n - 1)
        r = r_max * math.sin(math.pi * xi ** shape_a) ** 0.6
        if 0 < j < n - 1:
            r *= 1 + d.uniform("dr%d" % j, -0.15, 0.15)
        xs.append(xi * length)
        rs.append(r)
    rs[0] = 0.0
    rs[-1] = r_max * d.uniform("base_radius_ratio", 0.2, 0.6) if tail == "base" else 0.0
    pts = [(x, r) for x, r in zip(xs, rs)]
    if nose == "round" or tail == "round":
        # control polygon with a radial first/last leg: a tangent-continuous round end
        if nose == "round":
            pts.insert(1, (0.0, 0.5 * rs[1]))
        if tail == "round":
            pts.insert(len(pts) - 1, (length, 0.5 * rs[-2]))
        tags = [o.addPoint(x, r, 0) for x, r in pts]
        wall = o.addBSpline(tags)
        d.note("curve", "bspline (control points)")
    else:
        tags = [o.addPoint(x, r, 0) for x, r in pts]
        wall = o.addSpline(tags)
        d.note("curve", "spline (through points)")
    samples = profile_samples(wall)
    check_profile(samples, length, "body")
    p_end = tags[-1]
    curves = [wall]
    if rs[-1] > 0:
        p_end = o.addPoint(length, 0, 0)
        curves.append(o.addLine(tags[-1], p_end))
    curves.append(o.addLine(p_end, tags[0]))
    body = revolve_profile(curves)

    n_fins = d.choice("fins", [0, 3, 4])
    if n_fins == 0:
        return 1, "free"
    f = d.sub("fin")
    kind = f.choice("kind", ["box", "lofted"])
    chord = length * f.uniform("root_chord_ratio", 0.1, 0.25)
    span = r_max * f.uniform("span_ratio", 0.4, 1.2)
    # trailing edge where the body still has 40 % of its radius (fins must sit on the body)
    ok = [x for x, r in samples if r >= 0.4 * r_max]
    x_te = max(ok) - length * f.uniform("te_inset", 0.0, 0.05)
    chord = f.note("root_chord", min(chord, x_te - min(ok)))
    x_le = x_te - chord
    around = [r for x, r in samples if x_le <= x <= x_te]
    r_in, r_out = 0.5 * min(around), max(around) + span
    phase = f.uniform("phase_deg", 0.0, 360.0 / n_fins)
    if kind == "box":
        thick = chord * f.uniform("thickness_ratio", 0.03, 0.08)
        fin = o.addBox(x_le, -thick / 2, r_in, chord, thick, r_out - r_in)
    else:
        profile, t = draw_profile(f.sub("section"), (0.06, 0.12), 0.0, series=(4,))
        taper = f.uniform("taper", 0.3, 1.0)
        sweep = f.uniform("sweep_le_deg", 0.0, 50.0)
        te = draw_trailing_edge(f)
        tip = f.choice("tip", ["flat", "round"])
        secs = [{"z": z, "chord": chord * (1 - (1 - taper) * (z - r_in) / (r_out - r_in)),
                 "twist_deg": 0.0, "x_le": x_le + (z - r_in) * math.tan(math.radians(sweep)),
                 "y": 0.0, "t": t, "camber": 0.0} for z in (r_in, r_out)]
        fin = loft_wing({"profile": profile, "pivot": 0.25, "te_thickness": te, "tip": tip,
                         "sections": secs})
    # both kinds: chord along x, thickness along y, span along +z; copies spaced about the x axis
    fins = []
    for k in range(n_fins):
        copy = fin if k == 0 else volumes(o.copy([(3, fin)]))[0]
        o.rotate([(3, copy)], 0, 0, 0, 1, 0, 0, math.radians(phase) + 2 * math.pi * k / n_fins)
        fins.append(copy)
    fuse_all(body, fins, "fin fuse")
    return 1, "free"


def family_duct(d):
    """A fluid volume with planar open ends (inlet/outlet faces): the domain itself."""
    o = occ()
    kind = d.choice("kind", ["bent_pipe", "torus_bend", "tee", "nozzle", "rect_bend"])
    if kind in ("bent_pipe", "torus_bend"):
        r = d.uniform("radius", 0.06, 0.3)
        rb = r * d.uniform("bend_radius_ratio", 1.5, 4.0)
        angle = math.radians(d.uniform("bend_deg", 30.0, 180.0))
        l1, l2 = r * d.uniform("leg1_ratio", 2.0, 8.0), r * d.uniform("leg2_ratio", 2.0, 8.0)
        if kind == "torus_bend":
            bend = o.addTorus(0, 0, 0, rb, r, angle=angle)
            leg1 = o.addCylinder(rb, 0, 0, 0, -l1, 0, r)
            c, s = math.cos(angle), math.sin(angle)
            leg2 = o.addCylinder(rb * c, rb * s, 0, -l2 * s, l2 * c, 0, r)
            fuse_all(bend, [leg1, leg2], "torus bend fuse")
            return 1, "free"
        # a disk swept along line + arc(s) + line in the x-z plane
        trihedron = d.choice("trihedron", ["DiscreteTrihedron", "CorrectedFrenet"])
        arcs = 1 if angle <= math.radians(120) else 2
        center = o.addPoint(rb, 0, l1)
        pts = [o.addPoint(0, 0, 0), o.addPoint(0, 0, l1)]
        for k in range(1, arcs + 1):
            phi = angle * k / arcs
            pts.append(o.addPoint(rb - rb * math.cos(phi), 0, l1 + rb * math.sin(phi)))
        pts.append(o.addPoint(rb - rb * math.cos(angle) + l2 * math.sin(angle), 0,
                              l1 + rb * math.sin(angle) + l2 * math.cos(angle)))
        curves = [o.addLine(pts[0], pts[1])]
        curves += [o.addCircleArc(pts[k], center, pts[k + 1]) for k in range(1, arcs + 1)]
        curves.append(o.addLine(pts[-2], pts[-1]))
        wire = o.addWire(curves)
        disk = o.addDisk(0, 0, 0, r, r)
        one_volume(o.addPipe([(2, disk)], wire, trihedron), "pipe sweep")
        return 1, "free"
    if kind == "tee":
        r1 = d.uniform("main_radius", 0.06, 0.3)
        r2 = d.note("branch_radius", r1 * d.uniform("branch_ratio", 0.3, 0.9))
        lm = r1 * d.uniform("main_length_ratio", 6.0, 12.0)
        lb = r1 * d.uniform("branch_length_ratio", 3.0, 6.0)
        alpha = math.radians(d.uniform("branch_angle_deg", 45.0, 90.0))
        reach = r1 / math.tan(alpha) + r2 / math.sin(alpha) + r1
        x0 = d.uniform("branch_offset", -0.2, 0.2) * lm
        x0 = d.note("branch_x", max(-lm / 2 + reach, min(lm / 2 - reach - lb * math.cos(alpha), x0)))
        main = o.addCylinder(-lm / 2, 0, 0, lm, 0, 0, r1)
        branch = o.addCylinder(x0, 0, 0, lb * math.cos(alpha), 0, lb * math.sin(alpha), r2)
        fuse_all(main, [branch], "tee fuse")
        return 1, "free"
    if kind == "nozzle":
        length = d.uniform("length", 0.6, 3.0)
        r_in = length * d.uniform("inlet_ratio", 0.08, 0.2)
        r_t = d.note("throat_radius", r_in * d.uniform("throat_ratio", 0.3, 0.7))
        r_out = d.note("outlet_radius", r_t * d.uniform("outlet_ratio", 1.2, 3.0))
        xi_t = d.uniform("throat_position", 0.3, 0.6)
        n = d.integer("points", 5, 7)
        k_t = max(1, min(n - 2, round(xi_t * (n - 1))))
        pts = []
        for k in range(n):
            if k <= k_t:
                xi = xi_t * k / k_t
                r = r_t + (r_in - r_t) * (1 + math.cos(math.pi * xi / xi_t)) / 2
            else:
                xi = xi_t + (1 - xi_t) * (k - k_t) / (n - 1 - k_t)
                r = r_t + (r_out - r_t) * (1 - math.cos(math.pi * (xi - xi_t) / (1 - xi_t))) / 2
            pts.append(o.addPoint(xi * length, r, 0))
        wall = o.addSpline(pts)
        check_profile(profile_samples(wall), length, "nozzle")
        a_out, a_in = o.addPoint(length, 0, 0), o.addPoint(0, 0, 0)
        revolve_profile([wall, o.addLine(pts[-1], a_out), o.addLine(a_out, a_in),
                         o.addLine(a_in, pts[0])])
        return 1, "free"
    # rect_bend: a rectangle (x-y plane) revolved about the y axis, straight legs extruded
    w = d.uniform("width", 0.1, 0.5)
    h = w * d.uniform("height_ratio", 0.5, 2.0)
    rounded = w * d.choice("corner_radius_ratio", [0.0, 0.1, 0.25]) * min(1.0, h / w)
    rb = w / 2 + w * d.uniform("inner_bend_ratio", 0.3, 3.0)
    angle = math.radians(d.uniform("bend_deg", 30.0, 180.0))
    l1, l2 = w * d.uniform("leg1_ratio", 1.0, 4.0), w * d.uniform("leg2_ratio", 1.0, 4.0)
    rect = o.addRectangle(rb - w / 2, -h / 2, 0, w, h, roundedRadius=rounded)
    leg1 = one_volume(o.extrude([(2, rect)], 0, 0, l1), "duct leg")
    bend = one_volume(o.revolve([(2, rect)], 0, 0, 0, 0, 1, 0, angle), "duct bend")
    end = o.copy([(2, rect)])
    o.rotate(end, 0, 0, 0, 0, 1, 0, angle)
    leg2 = one_volume(o.extrude(end, -l2 * math.sin(angle), 0, -l2 * math.cos(angle)), "duct leg")
    fuse_all(leg1, [bend, leg2], "duct fuse")
    return 1, "free"


def family_block(d):
    """Box with pockets, blind/through holes and slots cut from its top, then edges filleted."""
    o = occ()
    lx = d.uniform("length", 0.6, 3.0)
    ly = lx * d.uniform("width_ratio", 0.4, 1.0)
    lz = lx * d.uniform("height_ratio", 0.15, 0.5)
    margin = 0.08 * min(lx, ly)
    box = o.addBox(0, 0, 0, lx, ly, lz)
    placed, tools, limits = [], [], [margin]
    for k in range(d.integer("features", 1, 4)):
        f = d.item("cuts")
        kind = f.choice("kind", ["rect_pocket", "rounded_pocket", "hole", "slot"])
        through = f.chance("through", 0.5) if kind in ("hole", "slot") else False
        depth = lz * 1.2 if through else lz * f.uniform("depth_ratio", 0.2, 0.7)
        if kind == "hole":
            sx = sy = 2 * min(lx, ly) * f.uniform("radius_ratio", 0.04, 0.15)
        else:
            sx, sy = lx * f.uniform("size_x_ratio", 0.1, 0.35), ly * f.uniform("size_y_ratio", 0.1, 0.35)
        for _ in range(100):     # a spot at least `margin` from the sides and the other cuts
            x0 = margin + (lx - 2 * margin - sx) * f.rng.random()
            y0 = margin + (ly - 2 * margin - sy) * f.rng.random()
            if all(x0 > a + w + margin or a > x0 + sx + margin or y0 > b + h + margin or b > y0 + sy + margin
                   for a, b, w, h in placed):
                break
        else:
            f.note("skipped", "no room")
            continue
        f.note("x", x0)
        f.note("y", y0)
        placed.append((x0, y0, sx, sy))
        z0 = lz - depth if not through else -0.1 * lz
        height = depth + 0.1 * lz if not through else 1.2 * lz
        if kind == "rect_pocket":
            tools.append(o.addBox(x0, y0, z0, sx, sy, height))
        elif kind == "hole":
            tools.append(o.addCylinder(x0 + sx / 2, y0 + sy / 2, z0, 0, 0, height, sx / 2))
        else:
            rr = min(sx, sy) * (0.4 if kind == "slot" else f.uniform("corner_ratio", 0.1, 0.3))
            rect = o.addRectangle(x0, y0, z0, sx, sy, roundedRadius=rr)
            tools.append(one_volume(o.extrude([(2, rect)], 0, 0, height), "pocket"))
        limits += [min(sx, sy) / 2] + ([] if through else [lz - depth, depth])
    if tools:
        out, _ = o.cut([(3, box)], [(3, t) for t in tools])
        box = one_volume(out, "pocket cut")
    o.synchronize()
    planes = [(0, 0.0), (0, lx), (1, 0.0), (1, ly), (2, 0.0), (2, lz)]
    eps = 1e-6 * lx
    outer, rims = [], []
    for _, c in gmsh.model.getEntities(1):
        bb = gmsh.model.getBoundingBox(1, c)
        on = [(a, v) for a, v in planes if abs(bb[a] - v) < eps and abs(bb[a + 3] - v) < eps]
        if len(on) == 2:
            where = "vertical" if {a for a, _ in on} == {0, 1} else "top" if (2, lz) in on else "bottom"
            outer.append((c, where))
        elif len(on) == 1 and on[0][0] == 2:
            rims.append(c)
    which = d.choice("fillet", ["vertical", "vertical+top", "all_outer", "rims", "vertical+rims"])
    kinds = {"all_outer": {"vertical", "top", "bottom"}}.get(which, set(which.split("+")))
    r_out = min(0.45 * margin, 0.3 * lz) * d.uniform("outer_radius_fraction", 0.2, 0.9)
    r_rim = 0.25 * min(limits) * d.uniform("rim_radius_fraction", 0.2, 0.9)
    edges = [c for c, where in outer if where in kinds]
    radii = [r_out] * len(edges)
    if "rims" in kinds:     # cut rims on the top (and, for through cuts, bottom) face
        edges += rims
        radii += [r_rim] * len(rims)
    d.note("filleted_edges", len(edges))
    d.note("outer_radius", r_out), d.note("rim_radius", r_rim)
    if edges:
        one_volume(o.fillet([box], edges, radii), "fillet")
    return 1, "free"


def family_close_bodies(d):
    """2 or 3 convex bodies centred on a line (or an L), gaps of 2-10 % of the pair's mean size.
    Every body is symmetric about its axes, so the gap between bounding boxes is the distance."""
    o = occ()
    n = d.integer("bodies", 2, 3)
    bodies = []
    for k in range(n):
        b = d.item("body")
        kind = b.choice("kind", ["sphere", "ellipsoid", "box", "cylinder"])
        size = b.uniform("size", 0.3, 1.2)
        if kind == "sphere":
            half = [size / 2] * 3
        elif kind == "cylinder":
            axis = b.choice("axis", [0, 1, 2])
            r = size / 2 * b.uniform("radius_ratio", 0.3, 1.0)
            half = [r, r, r]
            half[axis] = size / 2
        else:
            half = [size / 2, size / 2 * b.uniform("ratio_2", 0.4, 1.0),
                    size / 2 * b.uniform("ratio_3", 0.4, 1.0)]
            b.rng.shuffle(half)
            half = [round(h, 6) for h in half]
            b.note("half_extents", half)
        bodies.append({"kind": kind, "half": half, "size": size, "draw": b})
    layout = "line" if n == 2 else d.choice("layout", ["line", "corner"])
    centers = [[0.0, 0.0, 0.0]]
    for k in range(1, n):
        prev, cur = bodies[k - 1], bodies[k]
        gap = 0.5 * (prev["size"] + cur["size"]) * cur["draw"].uniform("gap_ratio", 0.02, 0.10)
        cur["draw"].note("gap", gap)
        if k == 2 and layout == "corner":
            top = max(bodies[0]["half"][1], bodies[1]["half"][1])
            centers.append([centers[1][0], top + gap + cur["half"][1], 0.0])
        else:
            centers.append([centers[k - 1][0] + prev["half"][0] + gap + cur["half"][0], 0.0, 0.0])
    for body, c in zip(bodies, centers):
        hx, hy, hz = body["half"]
        if body["kind"] == "sphere":
            o.addSphere(*c, hx)
        elif body["kind"] == "ellipsoid":
            s = o.addSphere(*c, 1.0)
            o.dilate([(3, s)], *c, hx, hy, hz)
        elif body["kind"] == "box":
            o.addBox(c[0] - hx, c[1] - hy, c[2] - hz, 2 * hx, 2 * hy, 2 * hz)
        else:
            a = body["draw"].params["axis"]
            start = [c[i] - (body["half"][i] if i == a else 0.0) for i in range(3)]
            vec = [2 * body["half"][i] if i == a else 0.0 for i in range(3)]
            o.addCylinder(*start, *vec, body["half"][(a + 1) % 3])
    return n, "free"


BUILDERS = {"wing": family_wing, "half_wing": family_half_wing, "wing_body": family_wing_body,
            "propeller": family_propeller, "revolved_body": family_revolved_body,
            "duct": family_duct, "block": family_block, "close_bodies": family_close_bodies}


# ----------------------------------------------------------------------------------------------
# One attempt: build, tidy, size, place, check, write, re-import

def remove_loose_entities():
    """Points, curves and faces not on a solid's boundary (construction leftovers) go."""
    occ().synchronize()
    keep = set()
    for _, v in gmsh.model.getEntities(3):
        for s in gmsh.model.getAdjacencies(3, v)[1]:
            keep.add((2, s))
            for c in gmsh.model.getAdjacencies(2, s)[1]:
                keep.add((1, c))
                keep.update((0, p) for p in gmsh.model.getAdjacencies(1, c)[1])
    loose = [e for dim in (2, 1, 0) for e in gmsh.model.getEntities(dim) if e not in keep]
    if loose:
        occ().remove(loose)
        occ().synchronize()


def model_bbox():
    boxes = [gmsh.model.getBoundingBox(3, v) for _, v in gmsh.model.getEntities(3)]
    return [min(b[i] for b in boxes) for i in range(3)] + [max(b[i] for b in boxes) for i in range(3, 6)]


def fit_and_place(d, motion):
    """A recorded random rotation (motion "free" only), a scale about the origin into SIZE_RANGE,
    then a recorded random shift (in x and y only for motion "plane")."""
    every = gmsh.model.getEntities(3)
    if motion == "free" and d.chance("rotated", 0.3):
        z, phi = d.uniform("axis_z", -1.0, 1.0), math.radians(d.uniform("axis_phi_deg", 0.0, 360.0))
        rho = math.sqrt(1 - z * z)
        occ().rotate(every, 0, 0, 0, rho * math.cos(phi), rho * math.sin(phi), z,
                     math.radians(d.uniform("angle_deg", 0.0, 180.0)))
        occ().synchronize()
    total = 1.0
    for _ in range(4):      # OCC's boxes of rotated curved faces are loose: repeat until inside
        bb = model_bbox()
        extent = max(bb[3] - bb[0], bb[4] - bb[1], bb[5] - bb[2])
        scale = min(1.0, SIZE_RANGE[1] / extent) * max(1.0, SIZE_RANGE[0] / extent)
        if scale == 1.0:
            break
        total *= scale
        occ().dilate(every, 0, 0, 0, scale, scale, scale)
        occ().synchronize()
    if total != 1.0:
        d.note("fit_scale", total)
    shift = [d.uniform("shift_" + a, -0.5, 0.5) for a in ("x", "y")]
    shift.append(d.uniform("shift_z", -0.5, 0.5) if motion == "free" else 0.0)
    occ().translate(every, *shift)
    occ().synchronize()


def solids_summary():
    vols = [v for _, v in gmsh.model.getEntities(3)]
    return {"solids": len(vols), "faces": len(gmsh.model.getEntities(2)),
            "volumes_m3": [occ().getMass(3, v) for v in vols], "bbox": model_bbox()}


def check_model(expected, what):
    s = solids_summary()
    if s["solids"] != expected:
        raise RuntimeError("%s: %d solids, expected %d" % (what, s["solids"], expected))
    if min(s["volumes_m3"]) <= 0:
        raise RuntimeError("%s: a solid with non-positive volume" % what)
    bb = s["bbox"]
    extent = max(bb[3] - bb[0], bb[4] - bb[1], bb[5] - bb[2])
    if not SIZE_RANGE[0] * 0.95 <= extent <= SIZE_RANGE[1] * 1.05:
        raise RuntimeError("%s: size %.3g m outside %s" % (what, extent, SIZE_RANGE))
    return s


def write_step_metres(path):
    """gmsh.write, then declare the length unit as metres (the numbers are the model's) and fix
    the header's timestamp."""
    gmsh.write(path)
    with open(path) as f:
        text = f.read()
    text, n = re.subn(r"(LENGTH_UNIT\(\)\s*NAMED_UNIT\(\*\)\s*)SI_UNIT\(\.MILLI\.,\.METRE\.\)",
                      r"\1SI_UNIT($,.METRE.)", text)      # one per solid's representation
    if n == 0:
        raise RuntimeError("STEP length unit not found")
    text = re.sub(r"(FILE_NAME\('[^']*',')[0-9T:-]+'", r"\g<1>2000-01-01T00:00:00'", text, count=1)
    with open(path, "w") as f:
        f.write(text)


def import_summary(path):
    """A STEP file read back in a clean model, in metres."""
    gmsh.clear()
    gmsh.option.setString("Geometry.OCCTargetUnit", "M")
    occ().importShapes(path)
    occ().synchronize()
    return solids_summary()


def same_solids(a, b):
    extent = max(a["bbox"][i + 3] - a["bbox"][i] for i in range(3))
    if a["solids"] != b["solids"] or a["faces"] != b["faces"]:
        return "solids/faces %d/%d read back as %d/%d" % (a["solids"], a["faces"], b["solids"], b["faces"])
    for u, v in zip(sorted(a["volumes_m3"]), sorted(b["volumes_m3"])):
        if abs(u - v) > 1e-4 * abs(u) + 1e-12:
            return "volume %.6g read back as %.6g" % (u, v)
    if max(abs(p - q) for p, q in zip(a["bbox"], b["bbox"])) > 1e-3 * extent:
        return "bounding box %s read back as %s" % (a["bbox"], b["bbox"])
    return None


def attempt(family, subseed, path):
    """Build one shape with sub-seed `subseed` and write it; returns (record, error)."""
    params = {}
    d = Draw(random.Random(subseed), params)
    try:
        gmsh.clear()
        bodies, motion = BUILDERS[family](d.sub("shape"))
        remove_loose_entities()
        fit_and_place(d.sub("placement"), motion)
        built = check_model(bodies, "built")
        write_step_metres(path)
        back = import_summary(path)
        problem = same_solids(built, back)
        if problem:
            raise RuntimeError("re-import: " + problem)
        return {"params": params, "bodies": bodies, "faces": built["faces"],
                "volumes_m3": [round(v, 9) for v in built["volumes_m3"]],
                "bbox": [round(v, 6) for v in built["bbox"]]}, None
    except Exception as e:    # OCC failures arrive as plain Exceptions from the Gmsh API
        return {"params": params}, str(e).strip().splitlines()[-1] if str(e).strip() else repr(e)


def attempt_worker(family, subseed, path, conn):
    devnull = os.open(os.devnull, os.O_WRONLY)      # OCCT's STEP writer talks on stdout
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    conn.send(attempt(family, subseed, path))
    gmsh.finalize()


def make_shape(seed, index, width, out, families):
    """Shape `index`: its family from Random(f"{seed}-{index}"), then attempts with sub-seeds
    f"{seed}-{index}-{k}", each in a child process (a crash or hang costs only that attempt)."""
    family = random.Random("%s-%d" % (seed, index)).choice(families)
    name = "rand_%s_%0*d_%s.step" % (seed, width, index, family)
    path = os.path.join(out, name)
    failed = []
    start = time.time()
    ctx = multiprocessing.get_context("fork")
    for k in range(MAX_ATTEMPTS):
        subseed = "%s-%d-%d" % (seed, index, k)
        parent, child = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=attempt_worker, args=(family, subseed, path, child))
        proc.start()
        child.close()
        result, timed_out = None, not parent.poll(ATTEMPT_TIMEOUT_S)
        if not timed_out:
            try:
                result = parent.recv()
            except EOFError:
                pass
        proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join()
        if result is None:
            result = ({}, "timeout after %d s" % ATTEMPT_TIMEOUT_S if timed_out
                      else "crashed (exit code %s)" % proc.exitcode)
        record, error = result
        if error is None:
            record = {"file": name, "index": index, "family": family, "subseed": subseed, **record,
                      "failed_attempts": failed, "seconds": round(time.time() - start, 2)}
            return record
        failed.append({"subseed": subseed, "error": error, "params": record.get("params", {})})
        if os.path.exists(path):
            os.remove(path)
    return {"file": None, "index": index, "family": family, "failed_attempts": failed,
            "seconds": round(time.time() - start, 2)}


# ----------------------------------------------------------------------------------------------
# Command line

def generate(args):
    families = args.families.split(",") if args.families else FAMILIES
    unknown = set(families) - set(FAMILIES)
    if unknown:
        sys.exit("random-cad: unknown families %s (known: %s)" % (sorted(unknown), ", ".join(FAMILIES)))
    os.makedirs(args.out, exist_ok=True)
    indices = [int(i) for i in args.only.split(",")] if args.only else range(args.n)
    if not args.only:
        for old in glob.glob(os.path.join(args.out, "rand_%s_*.step" % args.seed)):
            os.remove(old)
    width = max(3, len(str(max(args.n - 1, 0))))
    shapes = []
    start = time.time()
    for i in indices:
        rec = make_shape(args.seed, i, width, args.out, families)
        shapes.append(rec)
        retries = len(rec["failed_attempts"])
        note = "" if not retries else "  (%d retr%s: %s)" % (
            retries, "y" if retries == 1 else "ies", "; ".join(f["error"] for f in rec["failed_attempts"]))
        print("%4d %-14s %s %5.1f s%s" % (i, rec["family"], rec["file"] or "FAILED", rec["seconds"], note),
              flush=True)
    summary = {"generator": "scripts/random-cad.py", "gmsh": gmsh.__version__, "seed": args.seed,
               "n": args.n, "families": families, "units": "m", "shapes": shapes}
    with open(os.path.join(args.out, "shapes.json"), "w") as f:
        json.dump(summary, f, indent=1)
    failed = [s for s in shapes if not s["file"]]
    by_family = {}
    for s in shapes:
        by_family[s["family"]] = by_family.get(s["family"], 0) + 1
    print("random-cad: %d shapes in %.1f s (%s); %d retried attempts; %d failed; %s" % (
        len(shapes) - len(failed), time.time() - start,
        ", ".join("%s %d" % kv for kv in sorted(by_family.items())),
        sum(len(s["failed_attempts"]) for s in shapes), len(failed),
        os.path.join(args.out, "shapes.json")))
    return 1 if failed else 0


def check(directory):
    """Re-import every file of DIR/shapes.json in a fresh Gmsh, in metres, and compare."""
    with open(os.path.join(directory, "shapes.json")) as f:
        summary = json.load(f)
    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    bad = 0
    print("%-40s %6s %6s %10s  %s" % ("file", "solids", "faces", "size m", "verdict"))
    for s in summary["shapes"]:
        if not s["file"]:
            print("%-40s %s" % ("(shape %d)" % s["index"], "not generated"))
            bad += 1
            continue
        path = os.path.join(directory, s["file"])
        with open(path) as f:
            metres = "SI_UNIT($,.METRE.)" in f.read()
        try:
            got = import_summary(path)
        except Exception as e:
            print("%-40s import failed: %s" % (s["file"], e))
            bad += 1
            continue
        bb = got["bbox"]
        size = max(bb[3] - bb[0], bb[4] - bb[1], bb[5] - bb[2])
        problem = same_solids({"solids": s["bodies"], "faces": s["faces"], "volumes_m3": s["volumes_m3"],
                               "bbox": s["bbox"]}, got)
        if not metres:
            problem = "STEP does not declare metres"
        elif problem is None and not SIZE_RANGE[0] * 0.95 <= size <= SIZE_RANGE[1] * 1.05:
            problem = "size out of range"
        bad += problem is not None
        print("%-40s %6d %6d %10.3f  %s" % (s["file"], got["solids"], got["faces"], size, problem or "ok"))
    gmsh.finalize()
    print("check: %d of %d files ok" % (len(summary["shapes"]) - bad, len(summary["shapes"])))
    return 1 if bad else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", default="1", help="seed (any string; default 1)")
    ap.add_argument("--n", type=int, default=10, help="number of shapes (default 10)")
    ap.add_argument("--out", help="output folder")
    ap.add_argument("--families", help="comma-separated subset of: " + ", ".join(FAMILIES))
    ap.add_argument("--only", help="comma-separated shape indices to (re)make, e.g. 17,23")
    ap.add_argument("--check", metavar="DIR", help="re-import DIR's files and report; no generation")
    args = ap.parse_args()
    if args.check:
        return check(args.check)
    if not args.out:
        ap.error("--out is required")
    return generate(args)


if __name__ == "__main__":
    sys.exit(main())
