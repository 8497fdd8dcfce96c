"""Read a callgrind output file (Ir events only) into per-function self / inclusive
instruction counts and call counts, without callgrind_annotate.

    from callgrind_summary import parse
    prof = parse("callgrind.out")
    prof.inclusive("ep::Scene::distance_to_surface")   # summed over every function whose name contains it
    prof.calls("closest_callback")

Inclusive cost of a function = its self cost (all its source files, inlined code
included) + the inclusive cost callgrind records on each of its call sites.
Self-recursive calls are skipped so nothing is counted twice.
"""
from __future__ import annotations

import re
from collections import defaultdict

_DEF = re.compile(r"^(ob|fl|fi|fe|fn|cob|cfi|cfl|cfn)=\((\d+)\)(?: (.*))?$")
_PLAIN = re.compile(r"^(ob|fl|fi|fe|fn|cob|cfi|cfl|cfn)=(.*)$")


class Profile:
    def __init__(self):
        self.self_cost = defaultdict(int)
        self.call_cost = defaultdict(int)  # (caller, callee) -> inclusive cost of those calls
        self.call_count = defaultdict(int)  # callee -> calls
        self.objects = {}  # function -> object file
        self.total = 0

    def functions(self):
        return set(self.self_cost) | {c for _, c in self.call_cost}

    def _inc(self, fn):
        return self.self_cost.get(fn, 0) + sum(v for (a, b), v in self.call_cost.items() if a == fn and b != fn)

    def matching(self, pattern):
        return sorted(f for f in self.functions() if pattern in f)

    def inclusive(self, pattern):
        """Inclusive Ir of the functions whose name contains ``pattern`` (callers excluded
        when a matching function calls another matching one)."""
        fns = set(self.matching(pattern))
        total = 0
        for f in fns:
            inc = self._inc(f)
            # Remove calls between two matching functions (they would be counted twice).
            inc -= sum(v for (a, b), v in self.call_cost.items() if a == f and b in fns and b != f)
            total += inc
        return total

    def self_of(self, pattern):
        return sum(v for f, v in self.self_cost.items() if pattern in f)

    def calls(self, pattern):
        fns = set(self.matching(pattern))
        # Calls from outside the matching set only (a wrapper calling its worker is one call).
        return sum(v for (a, b), v in self._call_pairs.items() if b in fns and a not in fns)

    def object_of(self, fn):
        return self.objects.get(fn, "")


def parse(path) -> Profile:
    prof = Profile()
    prof._call_pairs = defaultdict(int)
    names = {k: {} for k in ("ob", "fl", "fn")}
    kind_of = {
        "ob": "ob",
        "cob": "ob",
        "fl": "fl",
        "fi": "fl",
        "fe": "fl",
        "cfi": "fl",
        "cfl": "fl",
        "fn": "fn",
        "cfn": "fn",
    }
    cur_fn = cur_ob = None
    callee = callee_ob = None
    pending_calls = None
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        for line in fh:
            line = line.rstrip("\n")
            if not line:
                continue
            c = line[0]
            if c.isdigit() or c in "+-*":
                parts = line.split()
                cost = int(parts[1]) if len(parts) > 1 else 0
                if pending_calls is not None:
                    prof.call_cost[(cur_fn, callee)] += cost
                    prof._call_pairs[(cur_fn, callee)] += pending_calls
                    prof.call_count[callee] += pending_calls
                    if callee_ob:
                        prof.objects.setdefault(callee, callee_ob)
                    pending_calls = None
                    callee_ob = None
                else:
                    prof.self_cost[cur_fn] += cost
                    prof.total += cost
                continue
            if line.startswith("calls="):
                pending_calls = int(line[6:].split()[0])
                continue
            m = _DEF.match(line)
            if m:
                key, ident, name = m.group(1), m.group(2), m.group(3)
                table = names[kind_of[key]]
                if name is not None:
                    table[ident] = name
                value = table.get(ident, ident)
            else:
                m = _PLAIN.match(line)
                if not m:
                    continue
                key, value = m.group(1), m.group(2)
            if key == "fn":
                cur_fn = value
                if cur_ob:
                    prof.objects.setdefault(cur_fn, cur_ob)
                callee_ob = None
            elif key == "ob":
                cur_ob = value
            elif key == "cfn":
                callee = value
            elif key == "cob":
                callee_ob = value
    return prof
