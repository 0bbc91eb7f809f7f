#!/usr/bin/env python3
"""Tests of tools/check_module_graph.py on small crates written to a
temporary folder: what it must find (a circle, an upward import, a long
function, a long file) and what it must leave alone (test code, paths
inside a file's own inline modules, uses of other crates, a parent using
its children).

    python3 tools/test_check_module_graph.py
"""

import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

CHECKER = Path(__file__).resolve().parent / "check_module_graph.py"


def write_crate(root, files):
    """A one-crate workspace at `root` with `files` under crates/demo/src."""
    crate = root / "crates" / "demo"
    (crate / "src").mkdir(parents=True)
    (crate / "Cargo.toml").write_text('[package]\nname = "demo"\n')
    (root / "server" / "src").mkdir(parents=True)
    (root / "server" / "Cargo.toml").write_text('[package]\nname = "srv"\n')
    (root / "server" / "src" / "lib.rs").write_text("//! empty\n")
    for name, text in files.items():
        path = crate / "src" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def check(files):
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        write_crate(root, files)
        done = subprocess.run(
            [sys.executable, str(CHECKER), str(root)], capture_output=True, text=True
        )
        return done.returncode, done.stdout


CLEAN = {
    "lib.rs": """
        //! A crate whose root only declares and re-exports.
        pub mod a;
        pub mod b;
        mod lasting;
        mod leaf;
        pub use a::A;
    """,
    "a.rs": """
        use crate::leaf::helper;
        use crate::leaf::{helper as h};
        use crate::b::{self, B};
        use crate::b as bas;
        pub struct A;
        mod inner {
            use super::A;
            fn f() -> usize { super::super::leaf::helper() }
        }
        #[cfg(test)]
        mod tests {
            use crate::A;
            use super::*;
        }
    """,
    "b.rs": """
        use std::collections::HashMap;
        use serde::Serialize;
        use crate::lasting;
        pub struct B;
        pub fn g() -> usize { crate::leaf::helper() }
    """,
    "lasting.rs": """
        pub struct Floor;
    """,
    "leaf.rs": """
        pub(crate) fn helper() -> usize { 1 }
        // crate::a::A in a comment is no use, nor is "crate::b" in a string.
        const S: &str = "crate::a::A";
    """,
}


failures = []
checks = []


def expect(name, condition, detail):
    checks.append(name)
    if not condition:
        failures.append(f"{name}: {detail}")


code, out = check(CLEAN)
expect("clean crate passes", code == 0 and "0 problems" in out, out)

code, out = check({**CLEAN, "b.rs": "use crate::a::A;\npub struct B;\n"})
expect("a circle is found", code == 1 and "import circle: crate::a, crate::b" in out, out)

code, out = check({**CLEAN, "leaf.rs": "use crate::A;\npub(crate) fn helper() -> usize { 1 }\n"})
expect(
    "an upward import through the root is found",
    code == 1 and "upward import: crate::leaf uses its ancestor crate" in out,
    out,
)

ring = {
    "lib.rs": "pub mod p;\npub mod q;\n",
    "p/mod.rs": "pub mod c;\npub use c::C;\n",
    "p/c.rs": "use crate::q::Q;\npub struct C;\n",
    "q.rs": "use crate::p::C;\npub struct Q;\n",
}
code, out = check(ring)
expect(
    "a circle through a parent's use of its child is found",
    code == 1 and "import circle: crate::p, crate::p::c, crate::q" in out,
    out,
)

nested = {
    "lib.rs": "pub mod p;\n",
    "p/mod.rs": "mod c;\npub struct Shared;\npub fn top() -> c::C { c::C }\n",
    "p/c.rs": "use super::Shared;\npub struct C;\n",
}
code, out = check(nested)
expect(
    "a child using its parent is found",
    code == 1 and "upward import: crate::p::c uses its ancestor crate::p" in out,
    out,
)

long_fn = "pub fn long() {\n" + "    let _x = 1;\n" * 160 + "}\n"
code, out = check({**CLEAN, "b.rs": long_fn})
expect("a long function is found", code == 1 and "fn long is 162 lines" in out, out)

long_file = "pub fn f() {}\n" * 801 + "#[cfg(test)]\nmod tests {\n" + "    // t\n" * 900 + "}\n"
code, out = check({**CLEAN, "b.rs": long_file})
expect("a long file is found, its tests not counted", code == 1 and "801 lines without its tests" in out, out)

tests_only = {**CLEAN, "b.rs": "pub struct B;\n#[cfg(test)]\nmod tests {\n    use crate::a::A;\n}\n"}
tests_only["a.rs"] = "use crate::b::B;\npub struct A;\n"
code, out = check(tests_only)
expect("test code may import from anywhere", code == 0, out)

for failure in failures:
    print("FAIL", failure)
print(f"{len(checks) - len(failures)} passed, {len(failures)} failed")
sys.exit(1 if failures else 0)
