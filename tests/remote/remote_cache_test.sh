#!/usr/bin/env bash
# End to end: nginx (WebDAV) on 127.0.0.1 as the shared remote cache of two "machines" (two
# empty local caches) running a small variant of the demo.
#   A  uploads every stage;
#   B  is served every stage remotely, its outputs byte-identical to A's;
#   B' finds one object corrupted on the server: a warning, that stage recomputes (and repairs
#      the server's copy), outputs still byte-identical;
#   C  with nginx stopped and a changed parameter: a warning, a local run, exit 0.
# usage: remote_cache_test.sh MESHFLOW_EXE SOURCE_DIR
set -uo pipefail
exe=$1
src=$2
here=$(cd "$(dirname "$0")" && pwd)
source "$here/nginx.sh"
work=$(mktemp -d "${TMPDIR:-/tmp}/meshflow-remote.XXXXXX")
trap 'stop_nginx; [ -n "${MESHFLOW_KEEP_TEST_DIRS:-}" ] || rm -rf "$work"' EXIT
source "$here/demo_small.sh"

start_nginx "$work/nginx" "$work/store" || exit 1
echo "nginx at $NGINX_URL (pid $NGINX_PID)"

# run NAME [args...]: meshflow run in $work/NAME with its own local cache; prints the seconds.
run() {
  local name=$1
  shift
  mkdir -p "$work/$name"
  local t0=$(date +%s%N)
  (cd "$work/$name" && "$exe" run "$wf" "${small[@]}" --cache "$work/$name/cache" "$@" >"$work/$name.log" 2>&1)
  local code=$?
  echo "$name: exit $code in $((($(date +%s%N) - t0) / 1000000)) ms"
  return $code
}
out() { echo "$work/$1/out/naca-wingtip"; }
# same_outputs A B: every output file of A's run is byte-identical in B's (report.json and report.html aside).
same_outputs() {
  local n=0
  for f in "$(out "$1")"/*; do
    # report.json and report.html hold timings and each stage's status (ran, cached, remote)
    [ "$(basename "$f")" = report.json ] && continue
    [ "$(basename "$f")" = report.html ] && continue
    cmp -s "$f" "$(out "$2")/$(basename "$f")" || fail "$2: $(basename "$f") differs from $1's"
    n=$((n + 1))
  done
  [ "$n" -ge 8 ] || fail "only $n output files in $(out "$1")"
  echo "$2: $n output files byte-identical to $1's"
}

run a --remote-cache "$NGINX_URL" || { cat "$work/a.log"; fail "machine A failed"; }
ra=$(out a)/report.json
[ "$(json "$ra" 'r["remote_cache"]["uploaded"]')" = "$stages" ] || { cat "$work/a.log"; fail "A uploaded $(json "$ra" 'r["remote_cache"]')"; }
[ "$(json "$ra" 'len(r["remote_cache"]["warnings"])')" = 0 ] || fail "A warned: $(json "$ra" 'r["remote_cache"]["warnings"]')"
echo "A: uploaded $stages stages, $(ls "$work/store/cas" | wc -l) objects, $(du -sk "$work/store" | cut -f1) KiB on the server"

# B: an empty cache, the URL from the environment.
MESHFLOW_REMOTE_CACHE=$NGINX_URL run b || { cat "$work/b.log"; fail "machine B failed"; }
rb=$(out b)/report.json
[ "$(json "$rb" 'r["remote_cache"]["served"]')" = "$stages" ] || fail "B: served $(json "$rb" 'r["remote_cache"]')"
[ "$(json "$rb" 'sum(1 for s in r["stages"] if s["status"] == "cached" and s["remote"])')" = "$stages" ] ||
  fail "B: not every stage was served remotely: $(json "$rb" '[(s["name"], s["status"], s["remote"]) for s in r["stages"]]')"
[ "$(json "$rb" 'r["remote_cache"]["uploaded"]')" = 0 ] || fail "B uploaded something"
same_outputs a b

# B': one object on the server corrupted (tet's mesh): a warning, tet runs again, the rest is served.
digest=$(json "$ra" 'r["outputs"]["linear"]["digest"]')
[ -f "$work/store/cas/$digest" ] || fail "tet's object $digest is not on the server"
printf 'not the mesh' > "$work/store/cas/$digest"
run b2 --remote-cache "$NGINX_URL" || { cat "$work/b2.log"; fail "machine B' failed"; }
rb2=$(out b2)/report.json
grep -q "does not match its digest" "$work/b2.log" || { cat "$work/b2.log"; fail "B': no warning for the corrupt object"; }
[ "$(json "$rb2" '[s["status"] for s in r["stages"] if s["name"] == "tet"][0]')" = ran ] || fail "B': tet was not recomputed"
[ "$(json "$rb2" 'r["remote_cache"]["served"]')" = $((stages - 1)) ] || fail "B': served $(json "$rb2" 'r["remote_cache"]')"
same_outputs a b2
[ "$(sha256sum < "$work/store/cas/$digest" | cut -d' ' -f1)" = "$digest" ] || fail "B' did not replace the corrupt object on the server"
echo "B': warned, tet recomputed, the server's object repaired"

# C: nginx stopped, split changed (a local miss): a warning and a local run, exit 0.
stop_nginx
mkdir -p "$work/c" && cp -r "$work/b/cache" "$work/c/cache"
run c --remote-cache "$NGINX_URL" --set split.layers=2 || { cat "$work/c.log"; fail "C failed with the remote down"; }
rc=$(out c)/report.json
grep -q "warning: remote cache" "$work/c.log" || { cat "$work/c.log"; fail "C: no warning with the remote down"; }
[ "$(json "$rc" 'len(r["remote_cache"]["warnings"])')" -ge 1 ] || fail "C: report.json has no warning"
[ "$(json "$rc" '[s["status"] for s in r["stages"] if s["name"] == "split"][0]')" = ran ] || fail "C: split did not run"
echo "C: remote down: $(json "$rc" 'r["remote_cache"]["warnings"][0]')"
echo "PASS"
