"""mkdocs hooks (mkdocs.yml): the repository's README is the site's home page, and the links the pages write for
GitHub (README.md beside docs/, docs/README.md as the contents) are turned into the site's.

- ``index.md`` is made from ../README.md, its links into docs/ made relative to docs/;
- docs/README.md (the contents, which GitHub shows for the folder) is published as ``contents.md``;
- a page's link to ``../README.md`` goes to ``index.md``, to ``README.md`` to ``contents.md``; a link to a README
  anchor whose section moved to a page of its own goes to that page.
"""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
# README sections that moved to docs/: anchor -> page
MOVED = {
    "translation-from-images-the-rig-bundle-adjustment": "method.md",
    "the-metric-trajectory-inside-the-adjustment": "method.md",
    "the-whole-extrinsic-on-line-the-rig-estimator": "method.md",
    "how-it-works": "method.md",
    "calibrating-your-own-rig": "guide.md",
    "exporting-the-result": "guide.md",
}
LINK = re.compile(r"\]\(([^)\s]+)\)")


def on_files(files, config):
    contents = files.get_file_from_path("README.md")
    if contents is not None:
        files.remove(contents)
        files.append(File.generated(config, "contents.md", content=contents.content_string))
    files.append(File.generated(config, "index.md", content=(ROOT / "README.md").read_text()))
    return files


def _target(link: str, home: bool) -> str:
    if re.match(r"[a-z]+:", link) or link.startswith("#"):
        return link
    path, _, anchor = link.partition("#")
    if home:  # README links are relative to the repository's root
        path = path.removeprefix("docs/") if path.startswith("docs/") else path
        path = "contents.md" if path == "README.md" else path
    elif path == "../README.md":
        path = MOVED.get(anchor, "index.md")
    elif path == "README.md":
        path = "contents.md"
    return path + (f"#{anchor}" if anchor else "")


def on_page_markdown(markdown, page, config, files):
    home = page.file.src_uri == "index.md"
    return LINK.sub(lambda m: f"]({_target(m.group(1), home)})", markdown)
