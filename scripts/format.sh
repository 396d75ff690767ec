#!/usr/bin/env bash
# Checks (default) or applies (--fix) clang-format on every C++ file in the repository, new files
# not yet added included (those .gitignore leaves out are not).
set -euo pipefail
cd "$(dirname "$0")/.."
mapfile -t files < <(git ls-files --cached --others --exclude-standard '*.cc' '*.h')
if [[ ${1:-} == --fix ]]; then
  clang-format -i "${files[@]}"
else
  clang-format --dry-run -Werror "${files[@]}"
  echo "format: ${#files[@]} files clean"
fi
