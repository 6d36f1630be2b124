"""The README and docs/ stay readable: short files, links that resolve, and no sentence about
how the work on the project was organised (the docs describe the product, results carry dates)."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
README_MAX_LINES = 120
DOC_MAX_LINES = 600

# Markdown links and images: [text](target) / ![alt](target).
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
# Figure paths named in running text or code spans, e.g. `docs/figures/x.png`.
FIGURE = re.compile(r"(?:docs/)?figures/[A-Za-z0-9_.-]+\.(?:png|jpg|jpeg|gif|svg)")

ORGANISATION_WORDS = [
    r"\bsessions?\b",
    # Ordinals from 9 to 18 ("...th"): the docs count in figures ("17 runs"); the lower
    # ordinals stay allowed ("the first frame").
    r"\b(nin|ten|eleven|twelf|thirteen|fourteen|fifteen|sixteen|seventeen|eighteen)th\b",
    r"\bthis round\b",
    r"\bround of work\b",
    r"\bclosing note\b",
    r"\bbefore this (change|work)\b",
    r"\bthe issue\b",
    r"\bissue \d+",
    r"\bnext design step\b",
    r"\blast time\b",
]


def md_files() -> list[Path]:
    return [README, *DOCS]


def test_there_are_docs_to_check():
    assert README.is_file() and len(DOCS) >= 8


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_doc_is_short(path: Path):
    lines = path.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= DOC_MAX_LINES, f"{path.name} has {len(lines)} lines"


def link_targets(path: Path) -> list[str]:
    """Relative link targets and figure paths of one Markdown file, anchors dropped."""
    text = path.read_text(encoding="utf-8")
    targets = [t for t in LINK.findall(text) if not re.match(r"^[a-z]+:", t) and not t.startswith("#")]
    return [t.split("#", 1)[0] for t in targets] + FIGURE.findall(text)


def resolve(path: Path, target: str) -> Path:
    """``docs/...`` is read from the repository root, anything else beside the file."""
    return ROOT / target if target.startswith("docs/") else path.parent / target


@pytest.mark.parametrize("path", md_files(), ids=lambda p: p.name)
def test_links_resolve(path: Path):
    missing = [t for t in link_targets(path) if not resolve(path, t).exists()]
    assert not missing, f"{path.name}: links to missing files: {missing}"


@pytest.mark.parametrize("path", md_files(), ids=lambda p: p.name)
def test_no_word_about_how_the_work_was_organised(path: Path):
    text = path.read_text(encoding="utf-8")
    hits = []
    for pattern in ORGANISATION_WORDS:
        for m in re.finditer(pattern, text, flags=re.IGNORECASE):
            line = text.count("\n", 0, m.start()) + 1
            hits.append(f"{path.name}:{line}: {m.group(0)!r}")
    assert not hits, "\n".join(hits)


def test_the_checks_can_fail(tmp_path: Path):
    doc = tmp_path / "x.md"
    doc.write_text("Figures from before this change.\n![f](figures/none.png)\n")
    assert any(re.search(p, doc.read_text(), re.IGNORECASE) for p in ORGANISATION_WORDS)
    assert not resolve(doc, link_targets(doc)[0]).exists()
