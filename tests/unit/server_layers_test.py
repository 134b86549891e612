#!/usr/bin/env python3
"""The include rule of docs/service.md, "Where the code lives":

- server/ is one folder per concept, and its folders include one way (ALLOWED below): config and
  wal use no other server folder; session builds on wal; auth on session and config; metrics on
  session; http on auth and session; service on auth and session. Only the top level of server/
  (main.cc and the start-up warm-up) may include every folder, and no folder includes the top
  level.
- clients/ and server/ never include each other; both may include the wire formats of proto/
  (the generated messages and the tile codec, "proto/codec/..."), which include neither.
- core/ includes none of server/, proto/codec or clients/.
- No product folder (core, proto, server, clients) includes tests/ code or gtest/gmock.
- Every "server/..." and "proto/codec/..." include anywhere in the repository names a file that
  exists (a moved header leaves no stale include behind).

Fails with the offending file, line and include.

Usage: server_layers_test.py REPO_ROOT
"""

import os
import re
import sys

# server/ folder -> the server folders its files may include (itself included).
ALLOWED = {
    "config": {"config"},
    "wal": {"wal"},
    "session": {"session", "wal"},
    "auth": {"auth", "session", "config"},
    "metrics": {"metrics", "session"},
    "http": {"http", "auth", "session"},
    "service": {"service", "auth", "session"},
}
PRODUCT = ("core", "proto", "server", "clients")
SOURCES = (".h", ".hpp", ".cc", ".cpp", ".cu", ".cuh")
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]')


def subdirs(path):
    return {d for d in os.listdir(path) if os.path.isdir(os.path.join(path, d))}


def sources(root, folder):
    for dirpath, dirnames, names in os.walk(os.path.join(root, folder)):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in sorted(names):
            if name.endswith(SOURCES):
                yield os.path.join(dirpath, name)


def includes(path):
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f, 1):
            m = INCLUDE.match(line)
            if m:
                yield number, m.group(1), line.strip()


def first(include):
    return include.split("/", 1)[0] if "/" in include else ""


def main(root):
    problems, counts = [], {}
    # The include roots of clients/ (rim_sim_lib and rimctl_lib: clients/; rim_client: clients/lib)
    # and of tests/ (tests/, tests/fuzz) name the first folder of their includes.
    clients_dirs = (subdirs(os.path.join(root, "clients")) |
                    subdirs(os.path.join(root, "clients", "lib")) | {"clients"})
    tests_dirs = (subdirs(os.path.join(root, "tests")) | {"tests", "gtest", "gmock"})

    def problem(path, number, text, why):
        problems.append(f"{os.path.relpath(path, root)}:{number}: {why}: {text}")

    for folder in PRODUCT:
        for path in sources(root, folder):
            counts[folder] = counts.get(folder, 0) + 1
            rel = os.path.relpath(path, os.path.join(root, folder)).split(os.sep)
            sub = rel[0] if len(rel) > 1 else ""
            for number, inc, text in includes(path):
                top = first(inc)
                if folder != "clients" and top in clients_dirs:
                    problem(path, number, text, f"{folder}/ includes clients/")
                if top in tests_dirs:
                    problem(path, number, text, f"{folder}/ includes test code")
                if folder == "clients" and top == "server":
                    problem(path, number, text, "clients/ includes server/ (shared code goes to "
                            "proto/ or core/)")
                if folder in ("core", "proto") and top == "server":
                    problem(path, number, text, f"{folder}/ includes server/")
                if folder == "core" and inc.startswith("proto/codec/"):
                    problem(path, number, text, "core/ includes proto/codec")
                if folder != "server" or top != "server":
                    continue
                parts = inc.split("/")
                target = parts[1] if len(parts) > 2 else ""
                if sub == "":
                    continue  # the top level (main.cc, warm-up) may include every folder
                if sub not in ALLOWED:
                    problem(path, number, text, f"server/{sub} is not a known folder; add it to "
                            "this test and to docs/service.md")
                elif target == "":
                    problem(path, number, text, f"server/{sub} includes the top level of server/")
                elif target not in ALLOWED[sub]:
                    problem(path, number, text, f"server/{sub} may include only "
                            f"{sorted(ALLOWED[sub])}, not server/{target}")

    for sub in sorted(subdirs(os.path.join(root, "server"))):
        if sub not in ALLOWED:
            problems.append(f"server/{sub}: not a known folder; add it to this test and to "
                            "docs/service.md")

    # Stale paths: every include of server/ or the codec names a file that exists.
    for folder in PRODUCT + ("tests",):
        for path in sources(root, folder):
            for number, inc, text in includes(path):
                if (inc.startswith(("server/", "proto/codec/")) and
                        not os.path.isfile(os.path.join(root, inc))):
                    problem(path, number, text, "no such file")

    for folder, least in (("server", 30), ("clients", 20), ("core", 40), ("proto", 2)):
        if counts.get(folder, 0) < least:
            problems.append(f"only {counts.get(folder, 0)} source files under {folder}/; "
                            "wrong root?")
    for p in problems:
        print(p)
    total = sum(counts.values())
    print(f"server_layers_test: {total} files, {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "."))
