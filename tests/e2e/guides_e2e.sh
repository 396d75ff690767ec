#!/usr/bin/env bash
# Runs every `sh` block of the guides (docs/guides/*.md), guide by guide, in a scratch folder that
# has the repository's body_map/, estimators/, sim/, patch_fw/ and tools/ at hand and build/tools on
# the PATH: a guide whose commands stop working fails here. `console` blocks need a robot; of
# those, the systemd units are checked with systemd-analyze verify.
#   tests/e2e/guides_e2e.sh BUILD_DIR [GUIDE.md ...]
set -euo pipefail
# shellcheck source-path=SCRIPTDIR source=e2e_lib.sh
source "$(dirname "$0")/e2e_lib.sh"
e2e_init "$@"
shift
guides=("$@")
((${#guides[@]})) || guides=("$src"/docs/guides/*.md)
# Loopback-only DDS for the guides that publish.
use_loopback_dds
export PATH=$build/tools:$PATH
fail=0
blocks=0
for guide in "${guides[@]}"; do
  name=$(basename "$guide" .md)
  dir=$work/$name
  mkdir -p "$dir"
  for d in body_map estimators dds sim patch_fw tools; do ln -s "$src/$d" "$dir/$d"; done
  python3 - "$guide" >"$dir/guide.sh" <<'PY'
import sys
# As a user's shell runs them: a pipeline's status is its last command's (no pipefail), so a
# tool that `head` or `grep -m1` stops early ends by SIGPIPE, as it should, without failing.
out, on, n = ["set -eu"], False, 0
for line in open(sys.argv[1]):
    s = line.rstrip("\n")
    if not on and s.strip() == "```sh":
        on, n = True, n + 1
        out.append(f"echo '--- block {n}'")
        continue
    if on and s.strip() == "```":
        on = False
        continue
    if on:
        out.append(s)
print("\n".join(out))
print(f"# {n} blocks")
PY
  n=$(grep -c "^echo '--- block" "$dir/guide.sh" || true)
  ((n)) || continue
  blocks=$((blocks + n))
  if (cd "$dir" && timeout 600 bash guide.sh >"$dir/out.txt" 2>&1); then
    echo "PASS $name: $n block(s)"
  else
    echo "FAIL $name: its commands failed; the end of their output:"
    tail -15 "$dir/out.txt"
    fail=1
  fi
done
# The systemd units of docs/guides/deploying.md, with the binaries of this build.
if command -v systemd-analyze >/dev/null; then
  for unit in "$src"/tools/systemd/*.service; do
    sed "s|/usr/local/bin/|$build/tools/|" "$unit" >"$work/$(basename "$unit")"
    if SYSTEMD_LOG_LEVEL=err systemd-analyze verify --man=no "$work/$(basename "$unit")" \
      >"$work/verify.txt" 2>&1 && ! grep -v 'sys-subsystem-net-devices' "$work/verify.txt" | grep -q .; then
      echo "PASS $(basename "$unit"): systemd-analyze verify"
    else
      echo "FAIL $(basename "$unit"): systemd-analyze verify"
      cat "$work/verify.txt"
      fail=1
    fi
  done
fi
echo "guides: $blocks block(s) run"
exit $fail
