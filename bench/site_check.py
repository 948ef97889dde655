"""The documentation site as a reader's browser shows it (run by hand; needs Playwright
and a Chromium: ``pip install playwright`` and ``apt-get install chromium``, or
``playwright install chromium``).

    python bench/site_check.py [--chromium /usr/bin/chromium] [--out site_shots]

Builds the site (``mkdocs build --strict``), serves it on a local port, and in headless
Chromium: opens the home page, follows the navigation to every page (each must answer
and carry its title), searches for a few things a new user looks for (each must find a
page), and writes screenshots of the home, benchmark, search and API pages to ``--out``;
then shoots the pages with the widest tables (:data:`WIDE`) at a laptop's and a phone's
width (:data:`WIDTHS`), and counts the tables whose right edge lies beyond the page with
no scroll to reach it (``cut``) and every request to a host other than the local one
(``outside``: a web font, a script from a CDN; the site must read offline).

Last line: ``SITE pages=<n> nav_ok=<n> searches_ok=<n>/<m> cut_tables=<n> outside_requests=<n> shots=<folder>``.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEARCHES = ("resume", "tune", "own robot", "solved", "mlflow", "rainbow")
WIDTHS = {"laptop": 1280, "phone": 390}
WIDE = ("", "getting-started/", "benchmark/", "reference/parameters/", "solved/")  # pages with wide tables
# A table whose content is wider than its box and whose box cannot scroll: cut at its edge.
CUT = """() => [...document.querySelectorAll('.md-typeset table')].filter(t => {
  const box = t.closest('.md-typeset__table') || t;
  const scrolls = ['auto', 'scroll'].includes(getComputedStyle(box).overflowX);
  return t.scrollWidth > box.clientWidth + 1 && !scrolls;
}).length"""


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # one line per request would drown the report
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chromium", default="/usr/bin/chromium", help="a Chromium executable ('' for Playwright's)")
    parser.add_argument("--out", type=Path, default=ROOT / "site_shots")
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    site = Path(tempfile.mkdtemp(prefix="site_"))
    subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)], cwd=ROOT, check=True,
                   env={"NO_MKDOCS_2_WARNING": "1", **__import__("os").environ})
    handler = functools.partial(_Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}"
    args.out.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(**({"executable_path": args.chromium} if args.chromium else {}),
                                    args=["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                                          "--disable-component-update", "--no-first-run"])
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.goto(base + "/")
        page.wait_for_timeout(1000)
        page.screenshot(path=str(args.out / "home.png"))
        hrefs = page.eval_on_selector_all("nav.md-nav--primary a.md-nav__link[href]", "els => els.map(e => e.href)")
        pages = sorted({h.split("#")[0] for h in hrefs})
        nav_ok = 0
        for href in pages:
            answer = page.goto(href)
            ok = answer is not None and answer.ok and "mujoco-rl-toolkit" in page.title()
            nav_ok += ok
            print(f"{'ok  ' if ok else 'FAIL'} {href.removeprefix(base)} {page.title()}")
        page.goto(base + "/benchmark/")
        page.wait_for_timeout(800)
        page.screenshot(path=str(args.out / "benchmark.png"))
        page.goto(base + "/reference/api/")
        page.wait_for_timeout(800)
        page.screenshot(path=str(args.out / "api.png"))
        found = 0
        for i, words in enumerate(SEARCHES):
            page.goto(base + "/")
            page.wait_for_timeout(600)
            page.keyboard.press("/")
            page.keyboard.type(words)
            page.wait_for_timeout(1500)
            hits = page.locator(".md-search-result__item").count()
            first = page.locator(".md-search-result__item a").first.get_attribute("href") if hits else None
            found += hits > 0
            print(f"search {words!r}: {hits} results, first {first}")
            if i == 0:
                page.screenshot(path=str(args.out / "search.png"))
        cut, outside = 0, []
        for name, width in WIDTHS.items():
            shot = browser.new_page(viewport={"width": width, "height": 900})
            shot.on("request", lambda r: outside.append(r.url) if not r.url.startswith((base, "data:")) else None)
            for path in WIDE:
                shot.goto(base + "/" + path)
                shot.wait_for_timeout(600)
                cut += shot.evaluate(CUT)
                label = path.strip("/").replace("/", "-") or "home"
                shot.screenshot(path=str(args.out / f"{label}-{name}.png"), full_page=path == "getting-started/")
            shot.close()
        for url in sorted(set(outside)):
            print(f"outside request: {url}")
        browser.close()
    server.shutdown()
    print(f"SITE pages={len(pages)} nav_ok={nav_ok} searches_ok={found}/{len(SEARCHES)} cut_tables={cut} "
          f"outside_requests={len(set(outside))} shots={args.out}")


if __name__ == "__main__":
    main()
