#!/usr/bin/env python3
"""core/ keeps its layers one-way (docs/core.md, "Layers"): every `#include "rim/..."` in a folder
of core/rim names a folder that the layer may use. Fails with the offending file, line and include.

Usage: core_layers_test.py CORE_RIM_DIR
"""

import os
import re
import sys

# Layer -> the layers its files may include (itself included). The top level of core/rim (the
# Mapper, the pipeline that ties everything together) is the last layer and may include them all.
ALLOWED = {
    "base": {"base"},
    "config": {"base", "config"},
    "io": {"base", "io"},
    "eval": {"base", "io", "eval"},
    "map": {"base", "config", "map"},
    "model": {"base", "config", "map", "model"},
    "train": {"base", "config", "map", "model", "train"},
    "mesh": {"base", "config", "map", "model", "mesh"},
    "gpu": {"base", "config", "map", "model", "gpu"},
}
TOP = set(ALLOWED) | {""}
INCLUDE = re.compile(r'^\s*#\s*include\s+"rim/(?:([a-z_]+)/)?[\w.]+"')


def main(root):
    problems, files = [], 0
    for dirpath, _, names in os.walk(root):
        layer = os.path.relpath(dirpath, root)
        layer = "" if layer == "." else layer.split(os.sep)[0]
        if layer and layer not in ALLOWED:
            problems.append(f"{dirpath}: folder '{layer}' is not a known layer; add it to this test "
                            "and to docs/core.md")
            continue
        allowed = ALLOWED.get(layer, TOP) if layer else TOP
        for name in sorted(names):
            if not name.endswith((".h", ".cc", ".cuh", ".cu")):
                continue
            files += 1
            path = os.path.join(dirpath, name)
            with open(path, encoding="utf-8") as f:
                for number, line in enumerate(f, 1):
                    m = INCLUDE.match(line)
                    if m and (m.group(1) or "") not in allowed:
                        target = m.group(1) or "the top level"
                        problems.append(f"{path}:{number}: layer '{layer or 'top'}' includes "
                                        f"{target}: {line.strip()}")
    if files < 40:
        problems.append(f"only {files} source files found under {root}; wrong folder?")
    for p in problems:
        print(p)
    print(f"core_layers_test: {files} files, {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "core/rim"))
