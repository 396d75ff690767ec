# shellcheck shell=bash disable=SC2034  # bin, work: set here for the sourcing script
# Shared by the end-to-end scripts that run in the CAN test VM (source it; bash).
#   e2e_begin NAME BUILD_DIR   sets $bin (the tools), makes and enters $work, zeroes the counts
#   ok NAME / bad NAME         one PASS / FAIL line
#   check_same NAME EXPECTED GOT   PASS when the two message lists are equal and not empty
#   e2e_end NAME               the summary line; returns non-zero if anything failed
#   guide_commands GUIDE.md [PROMPT]   the commands of the guide's `console` blocks, one a line:
#                              lines starting with PROMPT (an awk regex, default "[$#] ") without
#                              it, without a trailing "  # comment" and trailing spaces
e2e_begin() {
  bin=$(cd "${2:?usage: $1.sh BUILD_DIR}" && pwd)/tools
  work=${SKINBUS_VM_OUT:-$(mktemp -d)}/$1
  mkdir -p "$work"
  cd "$work" || exit 1
  pass=0
  fail=0
}
ok() { echo "PASS $1"; pass=$((pass + 1)); }
bad() { echo "FAIL $1"; fail=$((fail + 1)); }
check_same() {
  if [[ ! -s $2 ]]; then
    bad "$1: $2 is empty"
  elif diff -q "$2" "$3" >/dev/null; then
    ok "$1 ($(wc -l <"$2") messages)"
  else
    bad "$1: decoded output differs from what was sent ($(wc -l <"$2") sent, $(wc -l <"$3") decoded)"
    diff "$2" "$3" | cut -c1-160 | head -10 || true
  fi
}
guide_commands() {
  awk -v prompt="^(${2:-[\$#] })" '/^```console/ {on = 1; next} /^```/ {on = 0; next}
    on && $0 ~ prompt {sub(prompt, ""); sub(/  #.*/, ""); sub(/ +$/, ""); print}' "$1"
}
e2e_end() {
  echo "$1: $pass passed, $fail failed"
  ((fail == 0))
}
