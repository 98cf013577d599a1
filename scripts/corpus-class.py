#!/usr/bin/env python3
"""The failure class of one corpus run, from its report.json (the failed stage's error), its
run log and its exit code: one short name per cause, so that `make corpus` can count failures by
class (issue 42's table). Prints the class, or "-" for a run that ended valid.

    corpus-class.py EXIT_CODE RUN_DIR      (RUN_DIR holds log, init.log, out/report.json)
"""
import json
import os
import re
import sys

# (class, stage or "", regular expression on the error text); the first match wins
RULES = [
    ("init: no body found", "", r"every face of the domain lies on its bounding box"),
    ("init: unreadable file", "", r"cannot read|not valid ISO-10303|contains no shape"),
    ("init: blade section table needs --blades", "", r"how many blades"),
    ("heal: open surface model", "heal", r"not closed after sewing"),
    ("heal: edges shared by 3+ faces", "heal", r"shared by more than two faces"),
    ("heal: self-intersection", "heal", r"intersects itself"),
    ("heal: disconnected fluid", "heal", r"disconnected solids"),
    ("heal: slivers", "heal", r"narrower than the tolerance"),
    ("heal: invalid solid (BRepCheck)", "heal", r"validity check|BRepCheck"),
    ("heal: boolean failed", "heal", r"failed|fusing|cutting"),
    ("medial", "medial", r""),
    ("shell", "shell", r""),
    ("balance: out of memory", "balance", r"signal 9|memory"),
    ("balance", "balance", r""),
    ("sweep: folded parameter-plane mesh (pole)", "sweep", r"fold over"),
    ("sweep: prisms left inverted by the layer untangling", "sweep", r"stay inverted after untangling"),
    ("sweep: a face too small for its divisions", "sweep", r"no boundary loop of three points"),
    ("sweep: near field touches itself (junction end on a third face)", "sweep", r"not a manifold|touches itself"),
    ("sweep: edge nodes out of order", "sweep", r"out of order"),
    ("sweep", "sweep", r""),
    ("tet: TetGen crashed", "tet", r"signal"),
    ("tet: near-field surface crossing (refused before TetGen)", "tet", r"crosses itself, so TetGen is not run"),
    ("tet: near field touches itself", "tet", r"not a manifold"),
    ("tet: surface crossing", "tet", r"intersect|cross"),
    ("tet", "tet", r""),
    ("curve", "curve", r""),
    ("optimise: invalid elements left", "optimise", r""),
    # split keeps each element's validity (its sub-elements map a sub-domain of the parent's
    # reference element): an invalid split comes from the curved elements optimise left invalid
    ("optimise: curved elements left invalid (split inherits them)", "split", r"mesh optimise: [^\n]*invalid [1-9]"),
    ("split", "split", r""),
]


def main():
    code, run_dir = sys.argv[1], sys.argv[2]
    init_log = os.path.join(run_dir, "init.log")
    report = os.path.join(run_dir, "out", "report.json")
    if code == "init":
        text = open(init_log).read() if os.path.exists(init_log) else ""
        for name, stage, rx in RULES:
            if stage == "" and re.search(rx, text):
                print(name)
                return
        print("init: refused")
        return
    if code == "timeout":
        print("timeout")
        return
    stage, error = "", ""
    if os.path.exists(report):
        r = json.load(open(report))
        bad = [s for s in r.get("stages", []) if s.get("status") in ("failed", "invalid")]
        if bad:
            stage, error = bad[0]["name"], bad[0].get("error") or ""
        elif not r.get("ok", False):
            stage, error = "contract", r.get("error") or ""
    if not stage and code == "0":
        print("-")
        return
    log = os.path.join(run_dir, "log")
    text = error + "\n" + (open(log, errors="replace").read()[-4000:] if os.path.exists(log) else "")
    kind = stage.split("_")[0] if stage else ""
    for name, st, rx in RULES:
        if st and (kind == st or stage.startswith(st)) and re.search(rx, text):
            print(name)
            return
    print((stage or "run") + ": other (exit %s)" % code)


if __name__ == "__main__":
    main()
