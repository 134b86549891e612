"""A list of named checks for the end-to-end scripts: each prints `ok` or `FAIL` with what it
checked, and the script exits 1 when any failed, listing them, instead of stopping at the first."""

from __future__ import annotations

from typing import List


class Failures:
    def __init__(self) -> None:
        self.items: List[str] = []

    def check(self, ok: bool, what: str) -> None:
        print(("ok   " if ok else "FAIL ") + what, flush=True)
        if not ok:
            self.items.append(what)

    def report(self, name: str) -> int:
        print(f"{name}: {len(self.items)} failure(s)")
        for item in self.items:
            print("  -", item)
        return 1 if self.items else 0
