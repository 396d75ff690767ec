#!/usr/bin/env python3
"""Holds the project libraries' links against docs/architecture.md.

    tests/architecture/check_links.py BUILD/link_graph.txt docs/architecture.md

link_graph.txt (written by CMake at configure time): `library: dep dep ...`, the project
libraries each library links directly (public, private or interface). The document's table
"Who may depend on whom" has a row per library: | `library` | `folder/` | `dep`, `dep` ... |,
the libraries it may reach, directly or through others ("none" for none). Fails, naming every
library and the dependency it must not reach (and the chain that reaches it), when a library
reaches one its row does not allow, or when a library has no row or a row names no library.
"""
import re
import sys


def read_graph(path):
    graph = {}
    for line in open(path):
        if ":" not in line:
            continue
        lib, deps = line.split(":", 1)
        graph[lib.strip()] = deps.split()
    return graph


def read_rules(path):
    rules, in_table = {}, False
    for line in open(path):
        if line.startswith("## "):
            in_table = "who may depend on whom" in line.lower()
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not in_table or len(cells) < 3 or not cells[0].startswith("`"):
            continue
        lib = cells[0].strip("`")
        allowed = re.findall(r"`([a-z0-9_]+)`", cells[2])
        rules[lib] = set(allowed)
    return rules


def chains(graph, lib):
    """Every library `lib` reaches, with one chain that reaches it."""
    reach, todo = {}, [(lib, [lib])]
    while todo:
        node, path = todo.pop()
        for dep in graph.get(node, []):
            if dep not in reach:
                reach[dep] = path + [dep]
                todo.append((dep, path + [dep]))
    return reach


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    graph, rules = read_graph(sys.argv[1]), read_rules(sys.argv[2])
    problems, failed = [], set()
    if not rules:
        problems.append(f"{sys.argv[2]}: no 'Who may depend on whom' table")
    for lib in sorted(graph):
        if lib not in rules:
            problems.append(f"library {lib}: no row in {sys.argv[2]}")
            failed.add(lib)
            continue
        for dep, chain in sorted(chains(graph, lib).items()):
            if dep not in rules[lib]:
                problems.append(f"library {lib} must not link {dep}: {' -> '.join(chain)}")
                failed.add(lib)
    known = set(graph) | {d for deps in graph.values() for d in deps}
    for lib in sorted(set(rules) - known):
        problems.append(f"{sys.argv[2]}: row {lib} names no library of this build")
    for p in problems:
        print("FAIL", p)
    print(f"{len(graph) - len(failed)} passed, {len(failed)} failed")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
