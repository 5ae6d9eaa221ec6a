"""The README and the docs pages link only to files that are in the repository."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def test_every_relative_link_in_the_readme_and_docs_names_a_file_of_the_repository():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    missing = []
    for page in pages:
        for url in LINK.findall(page.read_text()):
            if re.match(r"^(https?:|mailto:|#)", url):
                continue
            target = (page.parent / url.split("#")[0]).resolve()
            if not target.exists():
                missing.append(f"{page.relative_to(ROOT)}: {url}")
    assert not missing, "links to files not in the repository:\n" + "\n".join(missing)
