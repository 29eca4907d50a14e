#!/usr/bin/env python3
"""Import cycles between a crate's modules (no dependencies).

    tools/import_cycles.py [SRC_DIR ...]      (default: src viewer/src)

A module imports another where its code names it (`use crate::a::b`,
`super::x`, a child module by its name in a `use`). A module and its own
ancestors or descendants share types both ways by Rust's design, so only
modules outside one another count. Prints each cycle with its edges and
exits 1 if there is one; test code (`tests.rs`, `#[cfg(test)] mod tests`)
is left out.
"""
import os
import re
import sys


def modules(root):
    """Module path (tuple) → file, for every .rs file under root."""
    out = {}
    for d, _, files in os.walk(root):
        for f in files:
            if not f.endswith(".rs") or f == "tests.rs":
                continue
            path = os.path.join(d, f)
            parts = os.path.relpath(path, root)[:-3].split(os.sep)
            if parts[-1] == "mod":
                parts = parts[:-1]
            if parts in (["lib"], ["main"]):
                parts = []
            out[tuple(parts)] = path
    return out


def code_of(path):
    src = open(path, encoding="utf-8").read()
    src = re.split(r"#\[cfg\(test\)\]\s*mod tests\s*\{", src)[0]
    src = "\n".join(l for l in src.split("\n") if not l.strip().startswith("//"))
    return re.sub(r'"(?:[^"\\]|\\.)*"', '""', src)


def use_paths(body):
    """The paths a `use` tree names: `a::{b, c::d}` → a::b, a::c::d."""
    body = re.sub(r"\s+", "", body)
    if "{" not in body:
        return [body]
    i = body.index("{")
    prefix, inner = body[:i], body[i + 1 : body.rindex("}")]
    parts, depth, cur = [], 0, ""
    for ch in inner:
        depth += ch == "{"
        depth -= ch == "}"
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    parts.append(cur)
    return [prefix + q for p in parts if p for q in use_paths(p)]


def edges(mods):
    def owner(path):
        for k in range(len(path), -1, -1):
            if tuple(path[:k]) in mods:
                return tuple(path[:k])
        return None

    out = {}
    for mod, path in mods.items():
        src = code_of(path)
        refs = [p for m in re.finditer(r"\buse\s+([^;]+);", src) for p in use_paths(m.group(1))]
        refs += re.findall(r"\b((?:crate|super)(?:::\w+)+)", src)
        targets = set()
        for r in refs:
            segs = [s for s in r.split("::") if s and s not in ("*", "self")]
            if not segs:
                continue
            if segs[0] == "crate":
                full = segs[1:]
            elif segs[0] == "super":
                base = list(mod)
                while segs and segs[0] == "super":
                    base, segs = base[:-1], segs[1:]
                full = base + segs
            elif tuple(list(mod) + segs[:1]) in mods:
                full = list(mod) + segs
            else:
                continue
            t = owner(full)
            if t is None or t == mod or t == mod[: len(t)] or mod == t[: len(mod)]:
                continue
            targets.add(t)
        out[mod] = targets
    return out


def cycles(graph):
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found, n = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def main():
    roots = sys.argv[1:] or ["src", "viewer/src"]
    bad = 0
    for root in roots:
        graph = edges(modules(root))
        for comp in cycles(graph):
            bad += 1
            name = lambda m: "/".join(m) or "(crate root)"
            print(f"{root}: import cycle: " + ", ".join(name(m) for m in comp))
            for a in comp:
                for b in sorted(graph[a] & set(comp)):
                    print(f"    {name(a)} -> {name(b)}")
        print(f"{root}: {len(graph)} modules, {len(cycles(graph))} import cycles")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
