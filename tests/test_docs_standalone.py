"""The repository stands alone: its code, docs and benchmarks point at nothing outside it.

A user who clones DataPipe has only the repository. Two checks: no text names a file of the
project's private notes or an absolute path of the machine it was written on, and every relative
link in the Markdown docs resolves to a file in the repository.
"""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ["datapipe", "docs", "benchmarks", "tests", "scripts", "README.md", "Makefile", "make",
           "pyproject.toml", "blender_manifest.toml"]
SUFFIXES = {".py", ".md", ".toml", ".json", ".mk", ".csv", ".txt", ""}
# the private notes' names and the workspace's absolute path, spelled so this file does not match
OUTSIDE = [re.compile(p) for p in (r"\bshared" + "/", r"/work" + "/", r"\bsl" + r"-notes\b",
                                   r"\bdesign" + r"\.md\b", r"\bbpy" + r"-notes\b", r"\bscanner" + r"-facts\b")]
MD_LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def _files():
    for name in SCANNED:
        p = ROOT / name
        paths = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
        for q in paths:
            if q.suffix in SUFFIXES and q.resolve() != Path(__file__).resolve() \
                    and ".cache" not in q.parts and "__pycache__" not in q.parts:
                yield q


def test_nothing_points_outside_the_repository():
    hits = []
    for f in _files():
        try:
            text = f.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if any(p.search(line) for p in OUTSIDE):
                hits.append(f"{f.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not hits, "references to files outside the repository:\n  " + "\n  ".join(hits)


def test_relative_markdown_links_resolve():
    broken = []
    for f in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in MD_LINK.findall(f.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+:", target):          # http(s):, mailto: ...
                continue
            if not (f.parent / target).exists():
                broken.append(f"{f.relative_to(ROOT)} -> {target}")
    assert not broken, "links to files that are not in the repository:\n  " + "\n  ".join(broken)
