#!/usr/bin/env bash
# s2r batch killed and run again (CTest: tests_batch_resume, label batch):
# three small captures of the synthetic rig, one broken on purpose; the batch
# is killed with SIGKILL once a step has finished, then run again. It must
# complete with no finished step redone (their records unchanged, each said
# "skipped"), leave no step process of the killed batch running, report the
# broken capture with its log and never let it stop the others, and rerun
# only that one with --retry-failed once it is repaired.
set -euo pipefail
s2r=${1:?usage: batch_resume_test.sh BUILD/app/s2r}
tmp=$(mktemp -d /tmp/s2r_batch_resume.XXXXXX)
trap 'pkill -9 -f "$tmp" 2>/dev/null || true; rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

for scene in blob bunny; do
  "$s2r" synth --scene $scene --views 8 --width 160 --height 120 --out "$tmp/caps/$scene" >/dev/null 2>&1
done
mkdir -p "$tmp/caps/broken"
printf '{"format": "s2r.session", "version": 1, ' >"$tmp/caps/broken/session.json"  # truncated

"$s2r" batch "$tmp/caps" --out "$tmp/res" >"$tmp/run1.log" 2>&1 &
pid=$!
for _ in $(seq 600); do
  compgen -G "$tmp/res/*/steps/reconstruct.json" >/dev/null && break
  sleep 0.05
done
kill -9 $pid 2>/dev/null || true
wait $pid 2>/dev/null || true
sleep 0.5
# The step that was running died with the batch.
if pgrep -f "s2r-engine .*$tmp/res" >/dev/null; then fail "a step of the killed batch is still running"; fi
done_before=$(cd "$tmp/res" && ls */steps/*.json 2>/dev/null | sort)
[ -n "$done_before" ] || fail "no step finished before the kill"
declare -A sums
for f in $done_before; do sums[$f]=$(md5sum <"$tmp/res/$f"); done

code=0
"$s2r" batch "$tmp/caps" --out "$tmp/res" >"$tmp/run2.log" 2>&1 || code=$?
cat "$tmp/run2.log"
[ $code -eq 1 ] || fail "exit $code with a broken capture (expected 1)"
for f in $done_before; do
  [ "$(md5sum <"$tmp/res/$f")" = "${sums[$f]}" ] || fail "$f was redone"
  cap=${f%%/*}
  step=$(basename "$f" .json)
  grep -q "$cap: $step: skipped" "$tmp/run2.log" || fail "$cap $step not reported skipped"
done
for cap in blob bunny; do
  grep -q '"state": "done"' "$tmp/res/$cap/status.json" || fail "$cap not done"
  [ -f "$tmp/res/$cap/eval/eval.csv" ] || fail "$cap has no eval"
done
grep -q '"state": "failed"' "$tmp/res/broken/status.json" || fail "broken not failed"
grep -q 'broken' "$tmp/res/index.html" || fail "no summary row for the broken capture"
# Failures first on the page.
first=$(grep -o '<tr class="[a-z]*"' "$tmp/res/index.html" | head -1)
[ "$first" = '<tr class="failed"' ] || fail "the first row is $first"

# Repaired: --retry-failed runs the broken one only.
rm -rf "$tmp/caps/broken"
"$s2r" synth --scene blob --views 6 --width 96 --height 72 --out "$tmp/caps/broken" >/dev/null 2>&1
"$s2r" batch --out "$tmp/res" --retry-failed >"$tmp/run3.log" 2>&1 || fail "retry: $(cat "$tmp/run3.log")"
grep -q "broken: reconstruct" "$tmp/run3.log" || fail "retry did not run the broken capture"
if grep -q "blob: \|bunny: " "$tmp/run3.log"; then fail "retry touched a capture that had not failed"; fi
"$s2r" batch --status "$tmp/res" >"$tmp/status.log" || fail "status after the retry: $(cat "$tmp/status.log")"
echo "batch resume: ok ($(echo "$done_before" | wc -l) steps kept across the kill)"
