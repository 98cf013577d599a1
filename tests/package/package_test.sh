#!/usr/bin/env bash
# The Debian package as a stranger gets it: cpack builds meshflow_<version>_<arch>.deb from the
# build folder (or MESHFLOW_DEB names one already built), `dpkg -x` unpacks it into a scratch
# folder, and its own binary, with a clean environment, from an empty folder:
#   - prints `--version` with the project's version and the commit (or says it has none);
#   - runs the demo workflow the package ships (share/doc/meshflow/examples/naca_wingtip.yaml,
#     copied into the empty folder): exit 0, report.json "ok" with a valid order-4 mesh;
#   - writes a workflow with `init` for the STEP file the package ships (the paper's wing) and
#     runs it: exit 0, report.json "ok".
# Also: the package declares the Debian package of every shared library the binary needs, the
# binary has no run path into the build folder, and the package holds the licence and schemas.
# Everything it makes is under one scratch folder, removed at exit.
#
#   tests/package/package_test.sh BUILD VERSION
set -euo pipefail
build="$(cd "$1" && pwd)"
version="$2"
scratch="$(mktemp -d /tmp/meshflow-package.XXXXXX)"
trap 'rm -rf "$scratch"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }

deb="${MESHFLOW_DEB:-}"
if [ -z "$deb" ]; then
  cpack -G DEB --config "$build/CPackConfig.cmake" -B "$scratch/pkg" > "$scratch/cpack.log" 2>&1 ||
    { cat "$scratch/cpack.log"; fail "cpack failed"; }
  deb="$(ls "$scratch"/pkg/meshflow_*.deb)"
fi
[ -f "$deb" ] || fail "no package: $deb"
echo "package: $(basename "$deb"), $(du -k "$deb" | cut -f1) KiB"
[ "$(dpkg-deb -f "$deb" Package)" = meshflow ] || fail "package name"
[ "$(dpkg-deb -f "$deb" Version)" = "$version" ] || fail "package version $(dpkg-deb -f "$deb" Version), project $version"

root="$scratch/root"
dpkg -x "$deb" "$root"
exe="$root/usr/bin/meshflow"
[ -x "$exe" ] || fail "no usr/bin/meshflow in the package"
for f in usr/share/doc/meshflow/LICENSE usr/share/doc/meshflow/README.md usr/share/doc/meshflow/CHANGELOG.md \
         usr/share/doc/meshflow/SOURCES.md usr/share/meshflow/schemas/workflow.schema.json \
         usr/share/meshflow/schemas/workflow-editor.json usr/share/doc/meshflow/examples/naca_wingtip.yaml \
         usr/share/doc/meshflow/examples/3d_bl_wing.stp; do
  [ -s "$root/$f" ] || fail "the package has no $f"
done
if objdump -p "$exe" | grep -E 'RPATH|RUNPATH' | grep -F "$build"; then fail "the binary's run path points into the build folder"; fi

# Every NEEDED library resolves to a Debian package the .deb depends on.
depends="$(dpkg-deb -f "$deb" Depends)"
echo "Depends: $depends"
for lib in $(objdump -p "$exe" | awk '/NEEDED/ {print $2}'); do
  path="$(ldconfig -p | awk -v l="$lib" '$1 == l && !found {print $NF; found = 1}')"
  [ -n "$path" ] || fail "$lib is not found by ldconfig"
  pkg="$(dpkg -S "$(readlink -f "$path")" 2>/dev/null | awk -F: 'NR == 1 {print $1}')" || true
  [ -n "$pkg" ] || pkg="$(dpkg -S "$path" 2>/dev/null | awk -F: 'NR == 1 {print $1}')" || true
  [ -n "$pkg" ] || fail "no Debian package holds $path ($lib)"
  echo "$depends" | tr ',|' '\n\n' | sed 's/(.*)//; s/ //g' | grep -xF "$pkg" > /dev/null || fail "$lib comes from $pkg, which the package does not depend on"
done

# From an empty folder, with nothing of the build's environment.
work="$scratch/empty"
mkdir -p "$work"
run() { (cd "$work" && env -i PATH=/usr/bin:/bin HOME="$scratch" "$exe" "$@"); }
v="$(run --version)"
echo "--version: $v"
echo "$v" | grep -qE "^meshflow ${version//./\\.} \(commit ([0-9a-f]{12}(, with uncommitted changes)?|unknown: built outside a git checkout)\)$" ||
  fail "--version says '$v'"

cp "$root/usr/share/doc/meshflow/examples/naca_wingtip.yaml" "$work/"
start=$(date +%s)
run run naca_wingtip.yaml > "$scratch/run.log" 2>&1 || { tail -30 "$scratch/run.log"; fail "meshflow run of the demo exited $?"; }
echo "demo: $(( $(date +%s) - start )) s"
/usr/bin/python3 - "$work/out/naca-wingtip" <<'PY' || fail "report.json of the demo"
import json, os, sys
out = sys.argv[1]
r = json.load(open(os.path.join(out, "report.json")))
assert r["ok"] is True and r["invalid"] is False and not r["problems"], (r["ok"], r["invalid"], r["problems"])
split = next(s for s in r["stages"] if s["name"] == "split")
c, m = split["stats"]["contract"], split["stats"]["mesh"]
assert c["invalid"] == 0 and c["degenerate"] == 0 and c["untagged_faces"] == 0, c
assert m["elements"]["prism"] > 0 and m["elements"]["tet"] > 0, m["elements"]
assert "prism4" in m["by_type"], m["by_type"]  # order 4
for f in r["outputs"]["mesh"]["files"]:
    assert os.path.getsize(os.path.join(out, f)) > 0, f
print("demo mesh:", m["elements"], "invalid", c["invalid"])
PY

cp "$root/usr/share/doc/meshflow/examples/3d_bl_wing.stp" "$work/"
run init 3d_bl_wing.stp -o wing.yaml > "$scratch/init.log" 2>&1 || { tail -30 "$scratch/init.log"; fail "meshflow init of the STEP wing"; }
grep -q "kind: step" "$work/wing.yaml" || fail "init wrote no step stage"
run run wing.yaml > "$scratch/run-wing.log" 2>&1 || { tail -30 "$scratch/run-wing.log"; fail "meshflow run of init's workflow for the STEP wing"; }
/usr/bin/python3 - "$work/out/3d-bl-wing/report.json" <<'PY' || fail "report.json of the STEP wing"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["ok"] is True and r["invalid"] is False, (r["ok"], r["invalid"], r["problems"])
kinds = [s["kind"] for s in r["stages"]]
assert kinds[0] == "step" and kinds[-1] == "split", kinds  # init's preflight ran the first stages
split = r["stages"][-1]
assert split["status"] == "ran" and split["stats"]["contract"]["invalid"] == 0, split["status"]
print("STEP wing:", split["stats"]["mesh"]["elements"], "invalid 0")
PY
echo "ok"
