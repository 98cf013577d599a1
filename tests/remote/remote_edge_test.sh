#!/usr/bin/env bash
# The remote cache's failure modes on a one-stage workflow: a URL that is not http(s) is exit 2
# before anything is made; a closed port, a server that never answers (within --remote-timeout)
# and a server refusing PUT (nginx without dav_methods: 405) are warnings and a local run, exit 0.
# usage: remote_edge_test.sh MESHFLOW_EXE SOURCE_DIR
set -uo pipefail
exe=$1
here=$(cd "$(dirname "$0")" && pwd)
source "$here/nginx.sh"
work=$(mktemp -d "${TMPDIR:-/tmp}/meshflow-remote-edge.XXXXXX")
hang_pid=""
trap 'stop_nginx; [ -z "$hang_pid" ] || kill "$hang_pid" 2>/dev/null; [ -n "${MESHFLOW_KEEP_TEST_DIRS:-}" ] || rm -rf "$work"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
json() { /usr/bin/python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print($2)" "$1"; }

cat > "$work/wing.yaml" <<YAML
meshflow: 1
name: remote-edge
stages:
  geometry: {kind: naca_wing, with: {profile: "0012", tip: flat, farfield_chords: 3}}
outputs:
  shape: {from: geometry}
YAML
cd "$work"
ms() { echo $((($(date +%s%N) - $1) / 1000000)); }

# Bad URLs: exit 2 with a clear message, no cache folder and no out/ made.
for url in ftp://cache.example.org cache.example.org:8080 http://alice:pw@cache.example.org "http://"; do
  "$exe" run wing.yaml --cache "$work/bad-cache" --remote-cache "$url" >bad.log 2>&1
  code=$?
  [ "$code" = 2 ] || { cat bad.log; fail "--remote-cache $url: exit $code, want 2"; }
  grep -q "is not a remote cache URL" bad.log || { cat bad.log; fail "--remote-cache $url: no clear message"; }
  [ ! -e "$work/bad-cache" ] && [ ! -e "$work/out" ] || fail "--remote-cache $url: made folders"
done
MESHFLOW_REMOTE_CACHE=file:///tmp "$exe" run wing.yaml --cache "$work/bad-cache" >bad.log 2>&1
[ $? = 2 ] && grep -q MESHFLOW_REMOTE_CACHE bad.log || { cat bad.log; fail "a bad MESHFLOW_REMOTE_CACHE is not exit 2"; }
echo "bad URLs: exit 2, nothing made: $(head -1 bad.log)"

# run NAME TIMEOUT URL: a local run with a warning, exit 0; prints the milliseconds.
run_warned() {
  local name=$1 timeout=$2 url=$3 t0=$(date +%s%N)
  "$exe" run wing.yaml --cache "$work/$name-cache" --out "$work/$name-out" --remote-cache "$url" \
    --remote-timeout "$timeout" --remote-connect-timeout "$timeout" >"$name.log" 2>&1
  local code=$? took=$(ms "$t0")
  [ "$code" = 0 ] || { cat "$name.log"; fail "$name: exit $code, want 0"; }
  grep -q "warning: remote cache" "$name.log" || { cat "$name.log"; fail "$name: no warning"; }
  [ "$(json "$work/$name-out/report.json" 'len(r["remote_cache"]["warnings"])')" -ge 1 ] || fail "$name: report.json has no warning"
  [ "$(json "$work/$name-out/report.json" 'r["stages"][0]["status"]')" = ran ] || fail "$name: the stage did not run"
  echo "$name: exit 0 in $took ms: $(grep -m1 'warning: remote cache' "$name.log")"
  LAST_MS=$took
}

# A closed port: refused at once.
port=$(free_port)
run_warned closed 5 "http://127.0.0.1:$port"
[ "$LAST_MS" -lt 4000 ] || fail "closed port: took $LAST_MS ms"

# A server that accepts and never answers: the lookup gives up after --remote-timeout (2 s),
# once (not again at upload).
hport=$(free_port)
/usr/bin/python3 -c 'import socket, sys, time
s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1); s.bind(("127.0.0.1", int(sys.argv[1]))); s.listen(8)
held = []
while True: held.append(s.accept()[0])' "$hport" &
hang_pid=$!
wait_port "$hport" || fail "the hanging server did not start"
base=$(date +%s%N)
"$exe" run wing.yaml --cache "$work/base-cache" --out "$work/base-out" >base.log 2>&1 || { cat base.log; fail "plain run failed"; }
base_ms=$(ms "$base")
run_warned hang 2 "http://127.0.0.1:$hport"
grep -q "timed out" hang.log || { cat hang.log; fail "hang: the warning does not say it timed out"; }
[ "$LAST_MS" -lt $((base_ms + 4500)) ] || fail "hang: took $LAST_MS ms (a run without remote: $base_ms ms; timeout 2 s)"
[ "$LAST_MS" -ge 1900 ] || fail "hang: returned in $LAST_MS ms, before the 2 s timeout"
echo "hang: a run without remote takes $base_ms ms"

# nginx without dav_methods: GET misses (404), PUT is refused (405): one warning, nothing uploaded.
start_nginx "$work/nginx" "$work/store" readonly || exit 1
run_warned readonly 10 "$NGINX_URL"
grep -q "HTTP 405" readonly.log || { cat readonly.log; fail "readonly: the warning does not name the 405"; }
[ "$(json "$work/readonly-out/report.json" 'r["remote_cache"]["uploaded"]')" = 0 ] || fail "readonly: uploaded"
echo "PASS"
