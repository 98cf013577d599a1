#!/usr/bin/env python3
"""Checks an MSH file against the rules of PyFR's Gmsh importer (`pyfr import`), as read in its
public source (pyfr/readers/gmsh.py): written here from those rules, not copied, so that a test can
tell whether `pyfr import` would take the file without installing PyFR (not in Debian).

Rules: ASCII (file type 0) version 2.2 or 4.1 with 8-byte data; physical names unique
(case-insensitive) and physical tags unique across dimensions; names `periodic...` match
`periodic[ _-]NAME[ _-](l|r)` and come in l/r pairs; at least one physical group of the highest
dimension (the volume); every element block's entity carries a physical tag (4.1); every element
type is one PyFR maps; node rows have three coordinates (no parametric nodes).

Prints `ok <nodes> <elements> <volume groups> <boundary groups> <periodic pairs>` and exits 0, or
prints `refused: <reason>` and exits 1.
"""
import re
import sys

# Gmsh element type -> nodes per element, for the types PyFR maps (lines through pyramids, orders 1-4)
PYFR_TYPES = {1: 2, 8: 3, 26: 4, 27: 5, 2: 3, 9: 6, 21: 10, 23: 15, 3: 4, 10: 9, 36: 16, 37: 25,
              4: 4, 11: 10, 29: 20, 30: 35, 5: 8, 12: 27, 92: 64, 93: 125, 6: 6, 13: 18, 90: 40, 91: 75,
              7: 5, 14: 14, 118: 30, 119: 55}


class Refused(Exception):
    pass


def sections(lines):
    """{name: [lines]} of the file's $Name ... $EndName sections."""
    out, i = {}, 0
    while i < len(lines):
        head = lines[i].strip()
        if not head:
            i += 1
            continue
        if not head.startswith('$'):
            raise Refused(f'line {i + 1}: expected a section, got {head[:40]!r}')
        name = head[1:]
        try:
            end = lines.index('$End' + name, i + 1)
        except ValueError:
            raise Refused(f'no $End{name}')
        out[name] = lines[i + 1:end]
        i = end + 1
    return out


def check(path):
    with open(path, 'rb') as f:
        raw = f.read()
    try:
        text = raw.decode('ascii')
    except UnicodeDecodeError:
        raise Refused('not an ASCII file (binary MSH)')
    sec = sections([l.rstrip('\r') for l in text.split('\n')])
    fmt = sec.get('MeshFormat', [''])[0].split()
    if len(fmt) != 3 or fmt[0] not in ('2.2', '4.1') or fmt[1] != '0' or fmt[2] != '8':
        raise Refused(f'MeshFormat {" ".join(fmt)!r}: PyFR takes "2.2 0 8" or "4.1 0 8"')
    if fmt[0] != '4.1':
        raise Refused('version 2.2: this checker covers 4.1 only')

    names = sec.get('PhysicalNames')
    if not names:
        raise Refused('no $PhysicalNames')
    seen_names, seen_tags, groups = set(), set(), []
    for l in names[1:]:
        m = re.match(r'(\d+) (\d+) "([^"]*)"$', l)
        if not m:
            raise Refused(f'malformed physical name line {l!r}')
        dim, tag, name = int(m[1]), int(m[2]), m[3].lower()
        if name in seen_names:
            raise Refused(f'duplicate physical name {name}')
        if tag in seen_tags:
            raise Refused(f'duplicate physical tag {tag}')
        seen_names.add(name)
        seen_tags.add(tag)
        groups.append((dim, tag, name))
    voldim = max(d for d, _, _ in groups)
    periodic, volumes, bounds = {}, [], []
    for dim, tag, name in groups:
        if name.startswith('periodic'):
            m = re.match(r'periodic[ _-]([a-z0-9]+)[ _-](l|r)$', name)
            if not m:
                raise Refused(f'periodic name {name!r} is not periodic_<name>_l / _r')
            periodic.setdefault(m[1], []).append(m[2])
        elif dim == voldim:
            volumes.append(name)
        else:
            bounds.append(name)
    if not volumes:
        raise Refused('no volume physical group')
    for k, sides in periodic.items():
        if sorted(sides) != ['l', 'r']:
            raise Refused(f'periodic pair {k} unpaired: {sides}')

    ent = sec.get('Entities')
    if ent is None:
        raise Refused('no $Entities')
    counts = [int(x) for x in ent[0].split()]
    tagged = set()
    row = 1 + counts[0]  # point entities: PyFR skips them
    for dim in (1, 2, 3):
        for _ in range(counts[dim]):
            f = ent[row].split()
            row += 1
            if int(f[7]) > 0:
                tagged.add((dim, int(f[0])))

    nodes = sec['Nodes']
    nblocks, nnodes = (int(x) for x in nodes[0].split()[:2])
    row = 1
    for _ in range(nblocks):
        d, t, parametric, n = (int(x) for x in nodes[row].split())
        if parametric:
            raise Refused(f'parametric node block (entity {d} {t})')
        row += 1 + n
        for l in nodes[row:row + n]:
            if len(l.split()) != 3:
                raise Refused(f'node row with {len(l.split())} values: {l!r}')
        row += n

    els = sec['Elements']
    nblocks, nels = (int(x) for x in els[0].split()[:2])
    row, total = 1, 0
    for _ in range(nblocks):
        d, t, etype, n = (int(x) for x in els[row].split())
        row += 1
        if etype not in PYFR_TYPES:
            raise Refused(f'element type {etype} (entity {d} {t}) is not one PyFR maps')
        if (d, t) not in tagged:
            raise Refused(f'element block of entity ({d}, {t}) has no physical tag')
        for l in els[row:row + n]:
            if len(l.split()) != 1 + PYFR_TYPES[etype]:
                raise Refused(f'element row with {len(l.split()) - 1} nodes for type {etype}')
        row += n
        total += n
    if total != nels:
        raise Refused(f'element count {total} != header {nels}')
    return f'ok {nnodes} {nels} {len(volumes)} {len(bounds)} {len(periodic)}'


if __name__ == '__main__':
    try:
        print(check(sys.argv[1]))
    except Refused as e:
        print('refused:', e)
        sys.exit(1)
