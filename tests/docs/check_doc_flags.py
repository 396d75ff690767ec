#!/usr/bin/env python3
"""Holds the documents' tool commands against the tools' own --help.

    tests/docs/check_doc_flags.py SOURCE_DIR BUILD_DIR/tools

Reads README.md and every docs/**/*.md. Wherever a line names a project tool (`skinbus-NAME`,
bare or with a path, e.g. `build/tools/skinbus-identify`), the options written after it on that
command (its continuation lines with a trailing backslash joined, up to a pipe or the end of the
inline code) must appear in that tool's --help (for skinbus-bench, skinbus-cmd and skinbus-mcap:
its subcommand's --help when one is named). Prints every option that does not, as FILE:LINE, and
exits 1; exits 0 when all do. A tool not built here (none of that name in BUILD_DIR/tools) is
skipped, and counted.
"""
import glob
import os
import re
import subprocess
import sys

SUBCOMMAND_TOOLS = ("skinbus-bench", "skinbus-cmd", "skinbus-mcap")
# A tool's name as a command: not part of a longer word (skinbus-bench-before, $skinbus-x).
TOOL = re.compile(r"(?:^|[\s`(|;])(?:[\w./$-]*/)?(skinbus-[a-z0-9]+(?:-[a-z0-9]+)*)(?![\w$-])(.*)")
OPTION = re.compile(r"(--[a-z][a-z0-9-]*)(?:=\S*)?[,.;:)'\"]*")


def main():
    src, bindir = sys.argv[1], sys.argv[2]
    helps = {}

    def help_of(tool, sub):
        key = (tool, sub)
        if key not in helps:
            exe = os.path.join(bindir, tool)
            if not os.path.isfile(exe):
                helps[key] = None
            else:
                args = [exe] + ([sub] if sub else []) + ["--help"]
                run = subprocess.run(args, capture_output=True, text=True, timeout=60)
                helps[key] = run.stdout + run.stderr
        return helps[key]

    files = [os.path.join(src, "README.md")]
    files += sorted(glob.glob(os.path.join(src, "docs", "**", "*.md"), recursive=True))
    checked, missing, skipped = 0, [], set()
    for path in files:
        lines = open(path, encoding="utf-8").read().split("\n")
        i = 0
        while i < len(lines):
            first = i
            m = TOOL.search(lines[i])
            if not m:
                i += 1
                continue
            tool, rest = m.group(1), m.group(2)
            while rest.rstrip().endswith("\\") and i + 1 < len(lines):
                i += 1
                rest = rest.rstrip()[:-1] + " " + lines[i]
            rest = re.split(r"[|`]", rest)[0]
            words = rest.split()
            sub = None
            if tool in SUBCOMMAND_TOOLS and words and re.fullmatch(r"[a-z][a-z0-9-]*", words[0]):
                sub = words[0]
            text = help_of(tool, sub)
            if text is None:
                skipped.add(tool)
                i += 1
                continue
            for word in words:
                o = OPTION.fullmatch(word)
                if not o:
                    continue
                checked += 1
                if not re.search(re.escape(o.group(1)) + r"(?![a-z0-9-])", text):
                    where = os.path.relpath(path, src)
                    missing.append(f"{where}:{first + 1}: {tool}{' ' + sub if sub else ''}: "
                                   f"{o.group(1)} is not in its --help")
            i += 1
    for line in missing:
        print(line)
    print(f"{checked} options of project tools checked in {len(files)} documents, "
          f"{len(missing)} not in the tool's --help"
          + (f"; tools not built here, skipped: {', '.join(sorted(skipped))}" if skipped else ""))
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
