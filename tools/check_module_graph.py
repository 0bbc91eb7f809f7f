#!/usr/bin/env python3
"""Keeps each crate's modules layered: no import circles, no imports from a
module's own ancestors, and no source file or function that grew too big.

For every crate of the workspace (each `src/lib.rs` or `src/main.rs` under
`crates/` and `server/`), the files are read as modules (`src/a/b.rs` and
`src/a/b/mod.rs` are `crate::a::b`) and every path that one module names of
another is an edge of the crate's module graph:

- `use crate::…`, `use super::…`, `use self::…` and uses of a child module
  by its bare name, with `{…}` groups expanded, `pub use` included (a
  re-export depends on what it re-exports);
- `crate::…` and `super::…` paths written in the code itself.

A path goes to the longest module it names (`crate::vpr::scan::ScalScan`
is an edge to `crate::vpr::scan`). Test code is left out: `#[cfg(test)]`
items and the files declared under `#[cfg(test)] mod …;` (tests may look
anywhere). Declaring a child module (`mod x;`) is ownership, not use.

It fails on:

1. a circle: modules that reach each other through uses (a strongly
   connected component of two or more);
2. an upward import: a module that uses one of its ancestors (`super::X`,
   `crate::X` from inside the crate, `crate::vpr::X` from inside
   `vpr/`); shared types belong in a leaf module both can use;
3. a source file of more than MAX_FILE_LINES lines not counting its test
   code, or a function of more than MAX_FN_LINES lines.

Standard library only:

    python3 tools/check_module_graph.py [--edges CRATE] [REPO_ROOT]

prints each problem as `crate: …` and exits 1 if any; `--edges CRATE`
also prints that crate's module graph, one `module -> used module` a line.
"""

import re
import sys
from pathlib import Path

MAX_FILE_LINES = 800
MAX_FN_LINES = 150


def strip_comments_and_strings(text):
    """The code with comments, string and char literals blanked (newlines kept)."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
            continue
        if text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
            continue
        m = re.match(r'b?r(#*)"', text[i:i + 12])
        if m and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            end = '"' + m.group(1)
            j = text.find(end, i + m.end())
            j = n if j < 0 else j + len(end)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
            continue
        if c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append(re.sub(r"[^\n]", " ", text[i:j + 1]))
            i = j + 1
            continue
        if c == "'":
            m = re.match(r"'(\\.|\\u\{[0-9a-fA-F]+\}|\\x..|[^\\'])'", text[i:i + 12])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
                continue
        out.append(c)
        i += 1
    return "".join(out)


def matching_brace(code, start):
    """Index just past the `}` that closes the `{` at `start`."""
    depth = 0
    for j in range(start, len(code)):
        if code[j] == "{":
            depth += 1
        elif code[j] == "}":
            depth -= 1
            if depth == 0:
                return j + 1
    return len(code)


CFG_TEST = re.compile(r"#\[cfg\((?:test|all\(test[^\]]*)\)\]")


def remove_test_code(code, spans=None):
    """The code without `#[cfg(test)]` items; and the test files it declares.
    The blanked `(start, end)` spans are added to `spans` when given."""
    test_mods = set()
    while True:
        m = CFG_TEST.search(code)
        if not m:
            return code, test_mods
        rest = m.end()
        # Further attributes may follow before the item.
        while True:
            a = re.match(r"\s*#\[[^\]]*\]", code[rest:])
            if not a:
                break
            rest += a.end()
        decl = re.match(r"\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", code[rest:])
        if decl:
            test_mods.add(decl.group(1))
            end = rest + decl.end()
        else:
            brace = code.find("{", rest)
            semi = code.find(";", rest)
            if brace < 0 or (0 <= semi < brace):
                end = semi + 1
            else:
                end = matching_brace(code, brace)
        if spans is not None:
            spans.append((m.start(), end))
        code = code[:m.start()] + re.sub(r"[^\n]", " ", code[m.start():end]) + code[end:]


def expand_use_tree(tree):
    """`a::{b, c::{d, e}}` -> [[a, b], [a, c, d], [a, c, e]] (segments)."""
    tree = re.sub(r"\s+as\s+", "@as@", tree)
    tree = re.sub(r"\s+", "", tree)
    results = []

    def walk(prefix, s):
        depth, parts, cur = 0, [], ""
        for ch in s:
            if ch == "," and depth == 0:
                parts.append(cur)
                cur = ""
                continue
            depth += ch == "{"
            depth -= ch == "}"
            cur += ch
        parts.append(cur)
        for part in parts:
            if not part:
                continue
            brace = part.find("{")
            if brace >= 0:
                head = [x for x in part[:brace].split("::") if x]
                walk(prefix + head, part[brace + 1:part.rfind("}")])
            else:
                path = part.split("@as@")[0]
                results.append(prefix + [x for x in path.split("::") if x])

    walk([], tree)
    return results


class Crate:
    def __init__(self, name, src):
        self.name = name
        self.src = src
        self.modules = {}  # module path tuple -> file
        root = src / "lib.rs" if (src / "lib.rs").exists() else src / "main.rs"
        self.root = root
        self._collect((), root)

    def _collect(self, path, file):
        self.modules[path] = file
        code, _ = remove_test_code(strip_comments_and_strings(file.read_text()))
        self_dir = file.parent if file.name in ("lib.rs", "main.rs", "mod.rs") else file.with_suffix("")
        for m in re.finditer(r"(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", code):
            name = m.group(1)
            child = None
            for candidate in (self_dir / f"{name}.rs", self_dir / name / "mod.rs"):
                if candidate.exists():
                    child = candidate
            if child is not None:
                self._collect(path + (name,), child)
        for m in re.finditer(r"(?:pub(?:\([^)]*\))?\s+)?\bmod\s+(\w+)\s*\{", code):
            # An inline module: a module of its own, read as part of its file.
            self.modules.setdefault(path + (m.group(1),), None)

    def resolve(self, here, segments):
        """The module (path tuple) a path names from module `here`, or None."""
        if not segments:
            return None
        if segments[0] == "crate":
            base, rest = (), segments[1:]
        elif segments[0] in ("super", "self"):
            base = here
            rest = list(segments)
            while rest and rest[0] in ("super", "self"):
                if rest[0] == "super":
                    base = base[:-1]
                rest = rest[1:]
        elif here + (segments[0],) in self.modules:
            base, rest = here, segments
        else:
            return None  # another crate, std, or an item of this module
        target = base
        for seg in rest:
            if target + (seg,) in self.modules:
                target = target + (seg,)
            else:
                break
        return target

    def edges(self):
        graph = {m: set() for m in self.modules}
        for module, file in self.modules.items():
            if file is None:
                continue
            code, _ = remove_test_code(strip_comments_and_strings(file.read_text()))
            # Inline modules (`mod x { … }`) are part of their file: paths in
            # them resolve from the inline module, and uses among a file's
            # own modules are not edges.
            inline = []
            for m in re.finditer(r"\bmod\s+(\w+)\s*\{", code):
                inline.append((m.end() - 1, matching_brace(code, m.end() - 1), m.group(1)))

            inline_names = {name for _, _, name in inline}

            def scope_at(pos):
                here = module
                for start, end, inline_name in sorted(inline):
                    if start < pos < end:
                        here = here + (inline_name,)
                return here

            def add(pos, segments):
                target = self.resolve(scope_at(pos), segments)
                own = target is not None and (
                    target == module
                    or (target[:len(module)] == module and target[len(module)] in inline_names)
                )
                if target is not None and not own:
                    graph[module].add(target)

            for m in re.finditer(r"\buse\s+([^;]+);", code):
                for segments in expand_use_tree(m.group(1)):
                    add(m.start(), segments)
            for m in re.finditer(r"(?<![\w:$])((?:crate|super)(?:::\w+)+)", code):
                add(m.start(), m.group(1).split("::"))
        return graph


def strongly_connected(graph):
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
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
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def name(path):
    return "::".join(("crate",) + path)


FN = re.compile(r"\bfn\s+\w+[^;{]*\{")


def size_problems(crate, repo):
    problems = []
    for file in sorted(set(f for f in crate.modules.values() if f is not None)):
        raw = file.read_text()
        spans = []
        code, _ = remove_test_code(strip_comments_and_strings(raw), spans)
        test_lines = set()
        for start, end in spans:
            test_lines.update(range(raw.count("\n", 0, start), raw.count("\n", 0, end) + 1))
        lines = raw.count("\n") + (not raw.endswith("\n")) - len(test_lines)
        rel = file.relative_to(repo)
        if lines > MAX_FILE_LINES:
            problems.append(f"{rel}: {lines} lines without its tests (at most {MAX_FILE_LINES})")
        for m in FN.finditer(code):
            end = matching_brace(code, m.end() - 1)
            body = code[m.start():end]
            count = body.count("\n") + 1
            if count > MAX_FN_LINES:
                line = code.count("\n", 0, m.start()) + 1
                fn_name = re.match(r"fn\s+(\w+)", m.group(0)).group(1)
                problems.append(f"{rel}:{line}: fn {fn_name} is {count} lines (at most {MAX_FN_LINES})")
    return problems


def main():
    args = sys.argv[1:]
    show_edges = None
    if args[:1] == ["--edges"]:
        show_edges, args = args[1], args[2:]
    repo = Path(args[0] if args else Path(__file__).resolve().parent.parent)
    crates = []
    for manifest in sorted(list(repo.glob("crates/*/Cargo.toml")) + [repo / "server/Cargo.toml"]):
        src = manifest.parent / "src"
        if (src / "lib.rs").exists() or (src / "main.rs").exists():
            crate_name = re.search(r'^name\s*=\s*"([^"]+)"', manifest.read_text(), re.M).group(1)
            crates.append(Crate(crate_name, src))
    problems = []
    for crate in crates:
        graph = crate.edges()
        if crate.name == show_edges:
            for module, targets in sorted(graph.items()):
                for target in sorted(targets):
                    print(f"{name(module)} -> {name(target)}")
        for comp in strongly_connected(graph):
            if len(comp) > 1:
                members = ", ".join(sorted(name(m) for m in comp))
                problems.append(f"{crate.name}: import circle: {members}")
        for module, targets in sorted(graph.items()):
            for target in sorted(targets):
                if module[:len(target)] == target:
                    problems.append(f"{crate.name}: upward import: {name(module)} uses its ancestor {name(target)}")
        problems += [f"{crate.name}: {p}" for p in size_problems(crate, repo)]
    for problem in problems:
        print(problem)
    modules = sum(len(c.modules) for c in crates)
    print(f"module graph: {len(crates)} crates, {modules} modules, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
