"""MkDocs hooks (mkdocs.yml ``hooks``): the home page is the repository's README.md, its
links into ``docs/`` made relative to the site, so the two never drift apart."""

from __future__ import annotations

from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri != "index.md":
        return markdown
    text = README.read_text().replace("](docs/", "](")
    return text.replace("MIT (`LICENSE`)", "MIT (the repository's `LICENSE`)")
