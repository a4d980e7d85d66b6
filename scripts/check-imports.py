#!/usr/bin/env python3
"""Import circles between the modules of each crate (ARCHITECTURE.md: "Modules import one way").

Reads every library and binary source file of the workspace's crates (tests, benches and
`#[cfg(test)]` modules left out) and draws an edge from a file to the module file each of its
`crate::…`, `super::…` and `self::…` paths names (the deepest module file the path reaches, so
an item re-exported by a folder's `mod.rs` counts as that `mod.rs`). Edges between a module
and its own ancestors or descendants are Rust's module tree, not imports between stages, and
are left out. A strongly connected set of two or more files is a circle: each is printed with
the path that closes it, and the script exits 1.

Usage: scripts/check-imports.py [CRATE_DIR...]   (default: every crate with a src/)
"""

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PATH_RE = re.compile(r"\b(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)+)")
USE_GROUP_RE = re.compile(r"\buse\s+(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)*)::\{([^;]*)\};", re.S)


def module_files(src: Path) -> dict[tuple[str, ...], Path]:
    """Module path (from the crate root) → its file, for every .rs file under src/. The roots
    (lib.rs, main.rs) are the empty path: every module descends from them, so they never
    close a circle."""
    mods: dict[tuple[str, ...], Path] = {}
    for f in sorted(src.rglob("*.rs")):
        rel = f.relative_to(src).with_suffix("").parts
        if rel[0] == "bin":
            continue
        if rel in (("lib",), ("main",)):
            mods.setdefault((), f)
            continue
        mods[rel[:-1] if rel[-1] == "mod" else rel] = f
    return mods


def strip(text: str) -> str:
    """The text without comments, string literals and `#[cfg(test)]` modules."""
    text = re.sub(r"//[^\n]*", "", text)
    text = re.sub(r'"(?:\\.|[^"\\])*"', '""', text)
    out, i = [], 0
    for m in re.finditer(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+\w+\s*\{", text):
        if m.start() < i:
            continue
        out.append(text[i : m.start()])
        depth, j = 1, m.end()
        while j < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        i = j
    out.append(text[i:])
    return "".join(out)


def resolve(base: tuple[str, ...], kind: str, rest: list[str], mods) -> tuple[str, ...] | None:
    if kind == "crate":
        path: tuple[str, ...] = ()
    elif kind == "self":
        path = base
    else:
        path = base[:-1]
        while rest and rest[0] == "super":
            path, rest = path[:-1], rest[1:]
    best = path if path in mods else None
    for part in rest:
        path = path + (part,)
        if path in mods:
            best = path
        else:
            break
    return best


def related(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    return a[: len(b)] == b or b[: len(a)] == a


def edges_of(src: Path) -> tuple[dict, dict]:
    mods = module_files(src)
    edges: dict[tuple, dict[tuple, str]] = {m: {} for m in mods}
    for mod, f in mods.items():
        text = strip(f.read_text(encoding="utf-8"))
        paths = [(k, r) for k, r in PATH_RE.findall(text)]
        for k, prefix, group in USE_GROUP_RE.findall(text):
            for item in re.split(r",", group):
                item = item.strip().split(" as ")[0].strip()
                if item and not item.startswith("{") and item != "self":
                    head = re.split(r"::\{", item)[0]
                    paths.append((k, prefix + "::" + head))
        for kind, rest in paths:
            parts = [p for p in rest.split("::") if p]
            target = resolve(mod, kind, parts, mods)
            if target is None or target == mod or related(mod, target):
                continue
            edges[mod].setdefault(target, f"{kind}::{'::'.join(parts)}")
    return mods, edges


def circles(edges: dict) -> list[list]:
    """Strongly connected components of two or more nodes (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(edges[root]))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            node, it = work[-1]
            advanced = False
            for nxt in it:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter[0]
                    counter[0] += 1
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(edges.get(nxt, {}))))
                    advanced = True
                    break
                if nxt in on:
                    low[node] = min(low[node], index[nxt])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                if len(comp) > 1:
                    out.append(comp)
    return out


def self_test() -> None:
    """A planted circle (a → b → a between siblings) is found; a parent's re-export is not one."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "src"
        (src / "m").mkdir(parents=True)
        (src / "lib.rs").write_text("pub mod m;\n")
        (src / "m" / "mod.rs").write_text("mod a;\nmod b;\npub use a::A;\n")
        (src / "m" / "a.rs").write_text("use super::b::B;\npub struct A;\n")
        (src / "m" / "b.rs").write_text("use crate::m::A; // the parent's re-export\npub struct B;\n")
        _, edges = edges_of(src)
        assert not circles(edges), f"a parent's re-export is no circle: {edges}"
        (src / "m" / "b.rs").write_text("use super::{a::A};\npub struct B;\n")
        _, edges = edges_of(src)
        found = circles(edges)
        assert len(found) == 1 and len(found[0]) == 2, f"the planted circle must be found: {edges}"


def main() -> int:
    self_test()
    crates = [Path(a).resolve() for a in sys.argv[1:]] or sorted(p.parent for p in ROOT.glob("*/src"))
    found = 0
    for crate in crates:
        mods, edges = edges_of(crate / "src")
        for comp in circles(edges):
            found += 1
            members = set(comp)
            print(f"check-imports: {crate.name}: an import circle of {len(comp)} files:")
            for m in sorted(comp):
                for t, via in sorted(edges[m].items()):
                    if t in members:
                        print(f"  {mods[m].relative_to(crate.parent)} → {mods[t].relative_to(crate.parent)} ({via})")
    if found:
        print("check-imports: modules must import one way (ARCHITECTURE.md); break each circle above")
        return 1
    print("check-imports: no import circle between modules")
    return 0


if __name__ == "__main__":
    sys.exit(main())
