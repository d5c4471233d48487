"""The documentation site's sources: every public name has an API reference entry, every
page is reachable from the index and the navigation, and no page links outside docs/
(which ``mkdocs build --strict`` would reject). Reads files only; the site itself is
built by ``make docs``."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: A Markdown link's target (without a #fragment).
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def public_names() -> list[str]:
    """``photonflow.__all__``, read from the package's source (no import)."""
    tree = ast.parse((ROOT / "src" / "photonflow" / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                getattr(target, "id", None) == "__all__" for target in node.targets):
            return list(ast.literal_eval(node.value))
    raise AssertionError("photonflow/__init__.py has no __all__")


def api_entries() -> set[str]:
    """Names documented in docs/api.md: ``::: photonflow.NAME`` directives, and the
    ``members:`` of a ``::: photonflow`` directive's options."""
    text = (DOCS / "api.md").read_text()
    names = set(re.findall(r"^::: photonflow\.(\w+)\s*$", text, re.MULTILINE))
    for block in re.findall(r"^::: photonflow\s*\n((?:[ \t]+.*\n?)*)", text, re.MULTILINE):
        members = yaml.safe_load(block) or {}
        names.update(members.get("options", {}).get("members", []) or [])
    return names


def pages() -> list[Path]:
    return sorted(DOCS.rglob("*.md"))


def nav_pages(entries) -> set[str]:
    """Every page file named in mkdocs.yml's ``nav``."""
    found = set()
    for entry in entries:
        values = entry.values() if isinstance(entry, dict) else [entry]
        for value in values:
            if isinstance(value, list):
                found |= nav_pages(value)
            else:
                found.add(value)
    return found


def test_every_public_name_has_an_api_entry():
    names = public_names()
    assert names, "empty __all__"
    missing = sorted(set(names) - api_entries())
    assert not missing, f"docs/api.md has no entry for photonflow.{', '.join(missing)}"


def test_api_entries_are_public_names():
    stale = sorted(api_entries() - set(public_names()))
    assert not stale, f"docs/api.md documents names not in photonflow.__all__: {stale}"


def test_index_links_every_page():
    index = DOCS / "index.md"
    linked = {(DOCS / target).resolve() for target in LINK.findall(index.read_text())}
    unlinked = [str(p.relative_to(DOCS)) for p in pages() if p != index and p not in linked]
    assert not unlinked, f"docs/index.md does not link {unlinked}"


def test_navigation_lists_every_page():
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=yaml.BaseLoader)
    assert config["docs_dir"] == "docs"
    listed = nav_pages(config["nav"])
    missing = [str(p.relative_to(DOCS)) for p in pages() if str(p.relative_to(DOCS)) not in listed]
    assert not missing, f"mkdocs.yml's nav does not list {missing}"
    absent = [name for name in listed if not (DOCS / name).is_file()]
    assert not absent, f"mkdocs.yml's nav lists missing pages {absent}"


def test_links_stay_inside_docs():
    """A relative link must reach a file inside docs/ (the repository's README,
    BENCHMARKS.md and studies/ are named in text, not linked)."""
    bad = []
    for page in pages():
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
        for target in LINK.findall(text):
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                continue
            path = (page.parent / target).resolve()
            if not path.is_relative_to(DOCS) or not path.exists():
                bad.append(f"{page.name}: {target}")
    assert not bad, bad


def test_docs_hold_documentation_only():
    """docs/ is the user's manual: pages and their pictures, no data or studies."""
    allowed = {".md", ".png", ".svg", ".jpg"}
    other = [str(p.relative_to(DOCS)) for p in DOCS.rglob("*")
             if p.is_file() and p.suffix not in allowed]
    assert not other, f"docs/ holds files that are not documentation: {other}"
