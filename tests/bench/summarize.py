#!/usr/bin/env python3
"""Prints the medians of a rim_bench JSON file (--benchmark_out) as a Markdown table.

usage: summarize.py BENCH.json [BENCH2.json ...]

With repetitions, the library's `_median` aggregate is used; without, the single run. Times are
wall clock in the benchmark's own unit; the counters follow.
"""
import json
import sys

SKIP_COUNTERS = {"items_per_second"}


def fmt(value):
    if abs(value) >= 1e6:
        return f"{value / 1e6:.3g}M"
    if abs(value) >= 1e4:
        return f"{value / 1e3:.4g}k"
    return f"{value:.4g}"


def rows(path):
    with open(path) as f:
        data = json.load(f)
    medians = {}
    singles = {}
    for b in data["benchmarks"]:
        name = b.get("run_name", b["name"])
        if b.get("aggregate_name") == "median":
            medians[name] = b
        elif b.get("run_type") == "iteration":
            singles.setdefault(name, b)
    for name in dict.fromkeys(list(singles) + list(medians)):
        yield name, medians.get(name, singles.get(name))


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        print(f"\n{path}\n")
        print("| benchmark | time | counters |")
        print("|---|---|---|")
        for name, b in rows(path):
            name = name.replace("/real_time", "")
            counters = ", ".join(
                f"{k}={fmt(v)}"
                for k, v in sorted(b.items())
                if isinstance(v, (int, float)) and k not in SKIP_COUNTERS and k not in (
                    "real_time", "cpu_time", "iterations", "repetitions", "repetition_index",
                    "threads", "family_index", "per_family_instance_index")
            )
            print(f"| {name} | {fmt(b['real_time'])} {b['time_unit']} | {counters} |")


if __name__ == "__main__":
    main()
