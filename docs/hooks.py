"""MkDocs hooks (mkdocs.yml ``hooks``): the home page is the repository's README.md, its
links into ``docs/`` made relative to the site, so the two never drift apart; and the
docstrings' Sphinx cross-reference roles (``:meth:`x```, which the code's readers in an
editor know) shown as plain code in the API pages, not as ":meth:" text."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri != "index.md":
        return markdown
    text = README.read_text().replace("](docs/", "](")
    # The README's way to this site is the site itself here: where to start instead.
    text = SERVE.sub("**Documentation:** this site. Start with [Getting started](getting-started.md).", text)
    return text.replace("MIT (`LICENSE`)", "MIT (the repository's `LICENSE`)")


SERVE = re.compile(r"\*\*Documentation:\*\*.*?Start with\s+\[Getting started\]\(getting-started\.md\)\.", re.S)


ROLE = re.compile(r":(?:meth|class|func|mod|attr|data|exc|obj):<code>~?")


def on_page_content(html: str, page, config, files) -> str:
    return ROLE.sub("<code>", html)
