"""``report.html``: the run's ``report.md`` as one self-contained HTML file (pictures embedded as data URIs), so it
can be mailed or attached to an issue without the folder around it."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from semmap.eval.report_md import MAP_VIEW_MARKER
from semmap.files.atomic import write_text_atomic

#: Pictures larger than this are linked instead of embedded (keeps the page small enough to open anywhere).
MAX_EMBEDDED_BYTES = 20 * 2**20
_IMG = re.compile(r'<img src="([^"]+)"')
_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; max-width: 60em; margin: 2em auto;
       padding: 0 1em; color: #222; line-height: 1.45; }
table { border-collapse: collapse; margin: 0.8em 0; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.7em; text-align: left; }
th { background: #f2f2f2; }
td:not(:first-child) { font-variant-numeric: tabular-nums; }
img { max-width: 100%; margin: 0.5em 0; }
code { background: #f4f4f4; padding: 0 0.2em; }
.map-view { border: 1px solid #ccc; margin: 0.8em 0; }
"""


def _embed(match: re.Match, base: Path) -> str:
    src = html.unescape(match.group(1))
    path = base / src
    if "://" in src or not path.is_file() or path.stat().st_size > MAX_EMBEDDED_BYTES:
        return match.group(0)
    kind = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}.get(
        path.suffix.lower(), "application/octet-stream")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img src="data:{kind};base64,{data}"'


def render_report_html(markdown: str, base_dir: str | Path, *, title: str = "semmap run",
                       map_view: str | None = None) -> str:
    """HTML page of a report's Markdown with the pictures it names (relative to ``base_dir``) embedded, and the
    map's 3D view (:mod:`semmap.viz.web_view`, plotly inlined) where the Markdown marks its place."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark").enable("table").render(markdown)
    body = _IMG.sub(lambda m: _embed(m, Path(base_dir)), body)
    if map_view is not None:
        body = body.replace(MAP_VIEW_MARKER, f'<div class="map-view">\n{map_view}\n</div>', 1)
    return (f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{html.escape(title)}"
            f"</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n{body}</body>\n</html>\n")


def write_report_html(path: str | Path, markdown: str, *, title: str = "semmap run",
                      map_view: str | None = None) -> Path:
    """Write ``report.html`` beside the pictures ``markdown`` names (with the map's 3D view when given)."""
    path = Path(path)
    return write_text_atomic(path, render_report_html(markdown, path.parent, title=title, map_view=map_view))
