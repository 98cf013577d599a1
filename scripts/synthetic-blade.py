#!/usr/bin/env python3
"""A synthetic compressor blade as a section file for `meshflow init FILE --blades N`.

Sections of a cambered NACA 4-digit-like profile (closed trailing edge) stacked on radius about
the x axis, hub to tip, each a closed loop from the leading edge along the suction side to the
trailing edge and back along the pressure side. Default: 6 sections, r = 15 .. 30 cm, chord
6 -> 7 cm, thickness 10% -> 5%, camber 6% -> 3%, stagger 25 -> 50 degrees, in cm.

Layouts (see docs/blade-rows.md):
  csv  x, y, z per point (x the machine axis)
  zrt  z, r, theta per point (z the machine axis, theta in degrees unless --radians)
Variants: --sep {comma,semicolon,space,tab}, --no-header, --section-column (a leading column with
the section number instead of blank lines between sections), --bom, --crlf, --units-comment.

usage: synthetic-blade.py OUT [--layout csv|zrt] [--sections 6] [--points 40] [...]
"""
import argparse
import math


def profile(n, chord, thick, camber, camber_pos=0.4):
    """(s, t) of a closed loop: LE -> suction side -> TE -> pressure side (TE and LE not repeated)."""
    xs = [0.5 * (1 - math.cos(math.pi * i / n)) for i in range(n + 1)]

    def half(x):
        return 5 * thick * (0.2969 * math.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3 - 0.1036 * x**4)

    def camb(x):
        m, p = camber, camber_pos
        if x < p:
            return m / p**2 * (2 * p * x - x * x), 2 * m / p**2 * (p - x)
        return m / (1 - p) ** 2 * ((1 - 2 * p) + 2 * p * x - x * x), 2 * m / (1 - p) ** 2 * (p - x)

    upper, lower = [], []
    for x in xs:
        yc, dy = camb(x)
        th = math.atan(dy)
        yt = half(x)
        upper.append((x - yt * math.sin(th), yc + yt * math.cos(th)))
        lower.append((x + yt * math.sin(th), yc - yt * math.cos(th)))
    loop = upper + lower[-2:0:-1]  # LE, suction side to TE, pressure side back (LE not repeated)
    return [(chord * (s - 0.5), chord * t) for s, t in loop]


def sections(args):
    out = []
    for k in range(args.sections):
        f = k / (args.sections - 1)
        r = args.hub + f * (args.tip - args.hub)
        chord = args.chord[0] + f * (args.chord[1] - args.chord[0])
        thick = args.thickness[0] + f * (args.thickness[1] - args.thickness[0])
        camber = args.camber[0] + f * (args.camber[1] - args.camber[0])
        stagger = math.radians(args.stagger[0] + f * (args.stagger[1] - args.stagger[0]))
        pts = []
        for s, t in profile(args.points, chord, thick, camber):
            x = s * math.cos(stagger) - t * math.sin(stagger)
            rt = s * math.sin(stagger) + t * math.cos(stagger)
            pts.append((x, r, rt / r))
        out.append(pts)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--layout", choices=["csv", "zrt"], default="csv")
    ap.add_argument("--sections", type=int, default=6)
    ap.add_argument("--points", type=int, default=40, help="intervals per side (a loop has 2*points points)")
    ap.add_argument("--hub", type=float, default=15.0)
    ap.add_argument("--tip", type=float, default=30.0)
    ap.add_argument("--chord", type=float, nargs=2, default=[6.0, 7.0])
    ap.add_argument("--thickness", type=float, nargs=2, default=[0.10, 0.05])
    ap.add_argument("--camber", type=float, nargs=2, default=[0.06, 0.03])
    ap.add_argument("--stagger", type=float, nargs=2, default=[25.0, 50.0], help="degrees, hub and tip")
    ap.add_argument("--sep", choices=["comma", "semicolon", "space", "tab"], default="comma")
    ap.add_argument("--no-header", action="store_true")
    ap.add_argument("--section-column", action="store_true")
    ap.add_argument("--radians", action="store_true", help="zrt: theta in radians")
    ap.add_argument("--bom", action="store_true")
    ap.add_argument("--crlf", action="store_true")
    ap.add_argument("--units-comment", default="", help="e.g. cm: writes '# units: cm'")
    args = ap.parse_args()
    sep = {"comma": ",", "semicolon": ";", "space": " ", "tab": "\t"}[args.sep]
    lines = []
    if args.units_comment:
        lines.append("# units: " + args.units_comment)
    if not args.no_header:
        cols = ["x", "y", "z"] if args.layout == "csv" else ["z", "r", "theta_rad" if args.radians else "theta_deg"]
        lines.append(sep.join((["section"] if args.section_column else []) + cols))
    for k, sec in enumerate(sections(args)):
        if k and not args.section_column:
            lines.append("")
        for x, r, th in sec:
            if args.layout == "csv":
                vals = [x, r * math.cos(th), r * math.sin(th)]
            else:
                vals = [x, r, th if args.radians else math.degrees(th)]
            row = ["%d" % (k + 1)] if args.section_column else []
            lines.append(sep.join(row + ["%.9g" % v for v in vals]))
    text = ("\r\n" if args.crlf else "\n").join(lines) + ("\r\n" if args.crlf else "\n")
    with open(args.out, "wb") as f:
        f.write((b"\xef\xbb\xbf" if args.bom else b"") + text.encode())


if __name__ == "__main__":
    main()
