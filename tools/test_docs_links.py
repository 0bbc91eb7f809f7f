#!/usr/bin/env python3
"""Checks every link of the project's Markdown: README.md, docs/**/*.md and
the other committed Markdown files (`git ls-files '*.md'`, without models/
and target/).

- A relative link must name a file or folder that exists, inside the
  repository (`/path` is taken from the repository's root, as GitHub does).
- A `#anchor`, alone or after a Markdown file, must be the slug of a heading
  of that file, by GitHub's rule: the heading's text as rendered, lowercased,
  every character that is not a letter, digit, mark, space, hyphen or
  underscore removed, spaces turned into hyphens; a repeated slug gets -1,
  -2, ... (`<a name>` and `id` attributes count too). Anchors into files
  that are not Markdown are not checked (GitHub's `#L12` line anchors).
- http(s), mailto and other URLs with a scheme are not fetched (no network).
- README.md stays a front page: under 200 lines.

Fenced code blocks and code spans are not Markdown, so brackets there are
not links and `#` lines there are not headings. Standard library only:

    python3 tools/test_docs_links.py [REPO_ROOT]

prints every broken link as `file:line: target: why` and exits 1 if any.
"""

import os
import re
import subprocess
import sys
import unicodedata
from pathlib import Path
from urllib.parse import unquote

README_MAX_LINES = 200

FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
ATX = re.compile(r"^ {0,3}(#{1,6})(?:[ \t]+(.*?))?(?:[ \t]+#+)?[ \t]*$")
SETEXT = re.compile(r"^ {0,3}(=+|-+)[ \t]*$")
CODE_SPAN = re.compile(r"(`+)(.+?)(?<!`)\1(?!`)", re.S)
# [text](target) and ![alt](target), with an optional "title"; the text may
# hold one level of brackets (`[see [x]](y)` is rare but legal).
INLINE_LINK = re.compile(
    r"!?\[(?P<text>(?:[^\[\]]|\[[^\[\]]*\])*)\]"
    r"\(\s*(?P<target><[^>\n]*>|[^\s()]*(?:\([^\s()]*\)[^\s()]*)*)"
    r"(?:\s+(?:\"[^\"]*\"|'[^']*'|\([^)]*\)))?\s*\)"
)
REFERENCE_DEF = re.compile(r"^ {0,3}\[(?P<label>[^\]]+)\]:\s*(?P<target><[^>]*>|\S+)")
HTML_LINK = re.compile(r"<(?:a|img)\b[^>]*?\b(?:href|src)\s*=\s*[\"']([^\"']*)[\"']", re.I)
HTML_ANCHOR = re.compile(r"<[a-z][^>]*?\b(?:name|id)\s*=\s*[\"']([^\"']+)[\"']", re.I)
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def blank_code_spans(text):
    """Replaces the contents of code spans by `x`, keeping offsets and line
    breaks, so that what is left is the Markdown that can hold links."""

    def fill(m):
        inner = re.sub(r"[^\n]", "x", m.group(2))
        return m.group(1) + inner + m.group(1)

    return CODE_SPAN.sub(fill, text)


def prose_lines(lines):
    """The lines with those of fenced code blocks emptied (line numbers kept)."""
    out, fence = [], None
    for line in lines:
        m = FENCE.match(line)
        if fence is None:
            if m:
                fence = m.group(1)
                out.append("")
                continue
            out.append(line)
        else:
            if m and m.group(1)[0] == fence[0] and len(m.group(1)) >= len(fence) and not line.strip()[len(m.group(1)):].strip():
                fence = None
            out.append("")
    return out


def rendered_text(heading):
    """A heading's text as GitHub renders it: code spans and emphasis
    unwrapped, links and images reduced to their text, HTML tags dropped."""
    text = re.sub(r"(`+)(.+?)\1", lambda m: m.group(2).strip(), heading)
    text = re.sub(r"!?\[((?:[^\[\]]|\[[^\[\]]*\])*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"<[^>]+>", "", text)
    text = re.sub(r"(\*{1,3})(\S(?:.*?\S)?)\1", r"\2", text)
    return text.strip()


def slug(heading):
    """GitHub's anchor for a heading (before de-duplication)."""
    kept = []
    for ch in rendered_text(heading).lower():
        if ch in " -_" or unicodedata.category(ch)[0] in "LNM":
            kept.append(ch)
    return "".join(kept).replace(" ", "-")


class Slugger:
    """Repeated slugs get -1, -2, ... as on GitHub."""

    def __init__(self):
        self.seen = {}

    def __call__(self, heading):
        base = slug(heading)
        result = base
        if base in self.seen:
            count = self.seen[base]
            while True:
                count += 1
                result = f"{base}-{count}"
                if result not in self.seen:
                    break
            self.seen[base] = count
        self.seen[result] = 0
        return result


def anchors(text):
    """Every anchor a Markdown file offers: its headings' slugs, and the
    names and ids of its HTML elements."""
    lines = prose_lines(text.split("\n"))
    slugger = Slugger()
    found = set()
    previous = ""
    for line in lines:
        m = ATX.match(line)
        if m:
            found.add(slugger(m.group(2) or ""))
            previous = ""
            continue
        m = SETEXT.match(line)
        if m and previous.strip() and not previous.lstrip().startswith(("|", ">", "-", "*", "+")):
            found.add(slugger(previous.strip()))
            previous = ""
            continue
        previous = line
    for m in HTML_ANCHOR.finditer(blank_code_spans("\n".join(lines))):
        found.add(m.group(1))
    found.discard("")
    return found


def links(text):
    """(line number, target) of every link of a Markdown text."""
    lines = prose_lines(text.split("\n"))
    prose = blank_code_spans("\n".join(lines))
    found = []

    def line_of(offset):
        return prose.count("\n", 0, offset) + 1

    for m in INLINE_LINK.finditer(prose):
        found.append((line_of(m.start()), m.group("target")))
    for m in HTML_LINK.finditer(prose):
        found.append((line_of(m.start()), m.group(1)))
    for number, line in enumerate(prose.split("\n"), 1):
        m = REFERENCE_DEF.match(line)
        if m:
            found.append((number, m.group("target")))
    found.sort()
    return found


def markdown_files(root):
    """README.md, docs/**/*.md and the committed Markdown files."""
    files = {root / "README.md"}
    files.update((root / "docs").rglob("*.md"))
    try:
        listed = subprocess.run(
            ["git", "-C", str(root), "ls-files", "-z", "--", "*.md"],
            check=True,
            capture_output=True,
        ).stdout.decode()
        files.update(root / p for p in listed.split("\0") if p)
    except (OSError, subprocess.CalledProcessError):
        for dirpath, dirnames, filenames in os.walk(root):
            dirnames[:] = [d for d in dirnames if d not in (".git", "build")]
            files.update(Path(dirpath) / f for f in filenames if f.endswith(".md"))
    skip = {"models", "target"}
    return sorted(
        f for f in files if f.is_file() and f.relative_to(root).parts[0] not in skip
    )


def check(root):
    """Every broken link under `root`, as printable lines."""
    root = root.resolve()
    problems = []
    anchor_cache = {}

    def anchors_of(path):
        if path not in anchor_cache:
            anchor_cache[path] = anchors(path.read_text(encoding="utf-8"))
        return anchor_cache[path]

    for md in markdown_files(root):
        rel = md.relative_to(root)
        for number, raw in links(md.read_text(encoding="utf-8")):
            target = raw[1:-1] if raw.startswith("<") and raw.endswith(">") else raw
            where = f"{rel}:{number}: {raw}"
            if SCHEME.match(target):
                continue  # http(s), mailto, ...: not fetched
            path_part, _, fragment = target.partition("#")
            path_part = unquote(path_part)
            if not path_part:
                if not target.startswith("#"):
                    problems.append(f"{where}: empty link")
                    continue
                dest = md
            elif path_part.startswith("/"):
                dest = (root / path_part.lstrip("/")).resolve()
            else:
                dest = (md.parent / path_part).resolve()
            if dest != root and root not in dest.parents:
                problems.append(f"{where}: points outside the repository")
                continue
            if not dest.exists():
                problems.append(f"{where}: no such file {dest.relative_to(root)}")
                continue
            if "#" not in target:
                continue
            fragment = unquote(fragment)
            if not fragment:
                problems.append(f"{where}: empty anchor")
            elif dest.is_file() and dest.suffix.lower() in (".md", ".markdown"):
                if fragment not in anchors_of(dest):
                    problems.append(
                        f"{where}: no heading with anchor #{fragment} in {dest.relative_to(root)}"
                    )
    readme = root / "README.md"
    count = len(readme.read_text(encoding="utf-8").splitlines())
    if count >= README_MAX_LINES:
        problems.append(
            f"README.md: {count} lines; the front page must stay under {README_MAX_LINES} "
            "(move the details into docs/)"
        )
    return problems


def self_test():
    cases = {
        "Operating a fleet server securely": "operating-a-fleet-server-securely",
        "`humem eval`: the protocol": "humem-eval-the-protocol",
        "Operating point: what a candidate's score means": "operating-point-what-a-candidates-score-means",
        "Verdicts: SLAM's geometric checks fed back into the ranking": "verdicts-slams-geometric-checks-fed-back-into-the-ranking",
        "Cluster mode: several servers, one store": "cluster-mode-several-servers-one-store",
        "Cluster mode (Kubernetes, compose)": "cluster-mode-kubernetes-compose",
        "Measured on town-dev/loop with verdicts (2026-12-04)": "measured-on-town-devloop-with-verdicts-2026-12-04",
        "`efficientnet_to_onnx.py`": "efficientnet_to_onnxpy",
        "**Bold** and [a link](x.md)": "bold-and-a-link",
        "Λ ∈ [0, 1]": "λ--0-1",
    }
    for heading, expected in cases.items():
        got = slug(heading)
        assert got == expected, f"slug({heading!r}) = {got!r}, expected {expected!r}"
    slugger = Slugger()
    got = [slugger(h) for h in ["Verdicts", "Verdicts", "Verdicts", "Verdicts 1"]]
    assert got == ["verdicts", "verdicts-1", "verdicts-2", "verdicts-1-1"], got

    sample = "\n".join(
        [
            "# Title",
            "## Title",
            "See [one](a.md#x) and ![pic](img/p.png \"t\"), `[not](code.md)` too.",
            "```sh",
            "# not a heading [not](fenced.md)",
            "```",
            "[ref]: ../b.md#y",
            '<a href="c.md">c</a> <a name="here"></a>',
            "Spans `across",
            "lines [not](span.md)` end.",
        ]
    )
    got = links(sample)
    expected = [(3, "a.md#x"), (3, "img/p.png"), (7, "../b.md#y"), (8, "c.md")]
    assert got == expected, got
    assert anchors(sample) == {"title", "title-1", "here"}, anchors(sample)


def main():
    self_test()
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent
    problems = check(root)
    if problems:
        print(f"{len(problems)} broken link(s) in the documentation:", file=sys.stderr)
        for p in problems:
            print("  " + p, file=sys.stderr)
        sys.exit(1)
    print(f"documentation links: {len(markdown_files(root.resolve()))} Markdown files, every link resolves")


if __name__ == "__main__":
    main()
