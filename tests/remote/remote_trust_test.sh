#!/usr/bin/env bash
# A shared cache that cannot be poisoned: nginx (WebDAV) on 127.0.0.1 as the remote cache of a
# small variant of the demo, every client with the team's key (MESHFLOW_REMOTE_KEY_FILE).
#   A        uploads every stage, each entry signed;
#   B        an empty cache, served every stage, outputs byte-identical to A's;
#   forged   tet's entry on the server rewritten to name another valid object (its preimage still
#            hashes to its key), once unsigned and once signed with another key: C (empty cache)
#            warns, recomputes tet, its outputs equal A's, its local cache holds tet's true
#            output and not the forged one, and the server's entry is C's signed true one;
#   no key   a client without the key says once that the remote is unauthenticated;
#   bad key  a missing or short key file: exit 2 with a message, before anything runs.
# usage: remote_trust_test.sh MESHFLOW_EXE SOURCE_DIR
set -uo pipefail
exe=$1
src=$2
here=$(cd "$(dirname "$0")" && pwd)
source "$here/nginx.sh"
work=$(mktemp -d "${TMPDIR:-/tmp}/meshflow-trust.XXXXXX")
trap 'stop_nginx; [ -n "${MESHFLOW_KEEP_TEST_DIRS:-}" ] || rm -rf "$work"' EXIT
source "$here/demo_small.sh"
openssl rand -hex 32 > "$work/team.key"
openssl rand -hex 32 > "$work/other.key"
export MESHFLOW_REMOTE_KEY_FILE=$work/team.key

start_nginx "$work/nginx" "$work/store" || exit 1
echo "nginx at $NGINX_URL (pid $NGINX_PID)"

# run NAME [args...]: meshflow run in $work/NAME with its own local cache.
run() {
  local name=$1
  shift
  mkdir -p "$work/$name"
  (cd "$work/$name" && "$exe" run "$wf" "${small[@]}" --cache "$work/$name/cache" --remote-cache "$NGINX_URL" "$@" \
     >"$work/$name.log" 2>&1)
  local code=$?
  echo "$name: exit $code"
  return $code
}
out() { echo "$work/$1/out/naca-wingtip"; }
same_outputs() {  # every output file of A's run byte-identical in B's (the reports aside)
  local n=0
  for f in "$(out "$1")"/*; do
    case "$(basename "$f")" in report.json | report.html) continue ;; esac
    cmp -s "$f" "$(out "$2")/$(basename "$f")" || fail "$2: $(basename "$f") differs from $1's"
    n=$((n + 1))
  done
  [ "$n" -ge 8 ] || fail "only $n output files in $(out "$1")"
  echo "$2: $n output files byte-identical to $1's"
}
stage_field() { json "$1" "[s['$3'] for s in r['stages'] if s['name'] == '$2'][0]"; }

run a || { cat "$work/a.log"; fail "A failed"; }
ra=$(out a)/report.json
[ "$(json "$ra" 'r["remote_cache"]["uploaded"]')" = "$stages" ] || fail "A uploaded $(json "$ra" 'r["remote_cache"]')"
[ "$(json "$ra" 'r["remote_cache"]["signed"]')" = True ] || fail "A: report says entries are not signed"
grep -q "unauthenticated" "$work/a.log" && fail "A has a key but says the remote is unauthenticated"
for f in "$work/store/ac/"*; do
  /usr/bin/python3 -c "import json,sys; e=json.load(open(sys.argv[1])); assert len(e['signature']) == 64" "$f" ||
    fail "entry $(basename "$f") on the server has no signature"
done
echo "A: $stages entries uploaded, each signed"

run b || { cat "$work/b.log"; fail "B failed"; }
[ "$(json "$(out b)/report.json" 'r["remote_cache"]["served"]')" = "$stages" ] || fail "B: served $(json "$(out b)/report.json" 'r["remote_cache"]')"
same_outputs a b

# The forgery: tet's entry names curve's output (a valid object on the server) as its own.
tet_key=$(stage_field "$ra" tet key)
true_digest=$(json "$ra" 'r["outputs"]["linear"]["digest"]')
other_digest=$(/usr/bin/python3 -c "import json,sys; e=json.load(open(sys.argv[1])); print(e['outputs'][0]['digest'])" \
  "$work/store/ac/$(stage_field "$ra" curve key)")
[ -n "$tet_key" ] && [ -f "$work/store/ac/$tet_key" ] || fail "tet's entry ac/$tet_key is not on the server"
[ -f "$work/store/cas/$other_digest" ] && [ "$other_digest" != "$true_digest" ] || fail "no other valid object to forge with"
cp "$work/store/ac/$tet_key" "$work/tet.entry"
forge() {  # forge HOW [KEYFILE]: rewrite tet's entry on the server (HOW: check | unsigned | otherkey)
  /usr/bin/python3 - "$work/store/ac/$tet_key" "$other_digest" "$1" "${2:-$work/other.key}" <<'PY'
import hashlib, hmac, json, sys
path, digest, how, other = sys.argv[1:5]
e = json.load(open(path))
def sign(entry, keyfile):  # as README says meshflow signs: HMAC-SHA256 of the canonical JSON
    key = open(keyfile, "rb").read().rstrip(b"\n")
    text = json.dumps(entry, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hmac.new(key, text.encode(), hashlib.sha256).hexdigest()
if how == "check":  # the honest entry's signature is the one the README describes
    given = e.pop("signature")
    sys.exit(0 if sign(e, other) == given else 1)
for o in e["outputs"]:
    o["digest"] = digest
if how == "otherkey":  # signed the same way, with a key that is not the team's
    e["signature"] = sign(e, other)
json.dump(e, open(path, "w"), indent=1)
PY
}
forge check "$work/team.key" || fail "tet's signature on the server is not HMAC-SHA256(team key, canonical JSON)"
for how in unsigned otherkey; do
  cp "$work/tet.entry" "$work/store/ac/$tet_key"
  forge "$how"
  name=c_$how
  run "$name" || { cat "$work/$name.log"; fail "$name failed"; }
  rc=$(out "$name")/report.json
  grep -q "entry of stage 'tet'.*\(is not signed\|does not verify\)" "$work/$name.log" ||
    { cat "$work/$name.log"; fail "$name: no warning for the forged entry"; }
  [ "$(stage_field "$rc" tet status)" = ran ] || fail "$name: tet was not recomputed"
  [ "$(json "$rc" 'r["remote_cache"]["served"]')" = $((stages - 1)) ] || fail "$name: served $(json "$rc" 'r["remote_cache"]')"
  same_outputs a "$name"
  kept=$(/usr/bin/python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['outputs'][0]['digest'])" \
    "$work/$name/cache/actions/$tet_key.json")
  [ "$kept" = "$true_digest" ] || fail "$name: the local cache's tet entry names $kept, not tet's true output"
  server=$(/usr/bin/python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['outputs'][0]['digest'])" "$work/store/ac/$tet_key")
  [ "$server" = "$true_digest" ] || fail "$name: the server's tet entry still names $server (forged entry re-uploaded?)"
  echo "$name: forged entry ($how) refused with a warning, tet recomputed, outputs as A's, the server's entry repaired"
done
# the consistency check of the local cache agrees
(cd "$work/c_unsigned" && "$exe" gc "$wf" --cache "$work/c_unsigned/cache" --verify >"$work/gc.log" 2>&1) ||
  { cat "$work/gc.log"; fail "gc --verify of C's cache found problems"; }

# No key: served (the entries are honest again) with one note that the remote is unauthenticated.
MESHFLOW_REMOTE_KEY_FILE= run nokey || { cat "$work/nokey.log"; fail "the client without a key failed"; }
[ "$(grep -c "is unauthenticated" "$work/nokey.log")" = 1 ] || { cat "$work/nokey.log"; fail "no key: the note is not said once"; }
[ "$(json "$(out nokey)/report.json" 'r["remote_cache"]["signed"]')" = False ] || fail "no key: report says signed"

# Bad key files: exit 2 before anything runs.
printf 'short\n' > "$work/short.key"
for k in "$work/missing.key" "$work/short.key" "$work"; do
  MESHFLOW_REMOTE_KEY_FILE=$k run badkey
  code=$?
  [ "$code" = 2 ] || { cat "$work/badkey.log"; fail "key file $k: exit $code, expected 2"; }
  grep -q "MESHFLOW_REMOTE_KEY_FILE" "$work/badkey.log" || { cat "$work/badkey.log"; fail "key file $k: the message does not name it"; }
done
echo "bad key files: exit 2, $(head -c 160 "$work/badkey.log")"
echo "PASS"
