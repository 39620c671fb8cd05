"""A results folder's `index.html`: one self-contained page (CSS inline, figures as data URIs, no script, nothing
fetched from a network) built from the folder's manifests like its README.md (`ident_opt.report.write_index`).

The page: the verdicts first (each study's `verdict` from its manifest: the recommended fit and why, warnings,
causes, changes, alarms), then each study's main Markdown rendered to HTML with its figures inlined where the
Markdown shows or links them, then the figures it lists but does not show, then links to its other files.
Markdown is rendered by Python-Markdown with raw HTML switched off, so every name that came from a user (files,
robots, joints) appears as text.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path, PurePosixPath
from urllib.parse import unquote, urlsplit

import markdown

from ident_opt import outputs

#: The page's file name in a results folder.
PAGE = "index.html"
#: Figure files inlined, with their MIME types.
IMAGES = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
#: Link schemes kept as links (navigation only: nothing on the page is fetched from them).
SCHEMES = {"http", "https", "mailto"}

CSS = """
body{font:15px/1.5 system-ui,-apple-system,"Segoe UI",sans-serif;color:#1d1d1f;margin:0;background:#f6f6f8}
main{max-width:1100px;margin:0 auto;padding:1rem 1.5rem 3rem;background:#fff}
h1{font-size:1.6rem;margin:.5rem 0 1rem}h2{border-bottom:2px solid #ddd;padding-bottom:.2rem;margin-top:2.2rem}
section.verdict{border:2px solid #2a6;border-radius:8px;background:#f1faf4;padding:.2rem 1.2rem 1rem}
section.verdict h2{border:0;margin-top:.6rem}section.verdict h3{margin-bottom:.2rem}
.scroll{overflow-x:auto;margin:.6rem 0}
table{border-collapse:collapse;font-size:13px;font-variant-numeric:tabular-nums}
th,td{border:1px solid #ccc;padding:.2rem .5rem;text-align:left;white-space:nowrap}
th{background:#eef0f4}tr:nth-child(even) td{background:#fafafa}
figure{margin:1rem 0}figure img,p img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:13px;color:#555}code{background:#f0f0f3;padding:0 .2rem;border-radius:3px}
.missing{color:#a33}.files{font-size:13px;color:#555}
"""


def write_page(root: Path, manifests: list[dict]) -> Path:
    """`root`/index.html from `manifests` (as `report._manifests` gives them: files relative to `root`, main
    reports — a README head or tail — first in the README's order), atomically. Returns its path."""
    path = Path(root) / PAGE
    outputs.write_text(path, page(Path(root), manifests))
    return path


def page(root: Path, manifests: list[dict]) -> str:
    """The HTML text of the page (`write_page`)."""
    main = [m for m in manifests if m["readme_head"] or m["readme_tail"]]
    others = [m for m in manifests if m not in main]
    anchors = {m["files"][0]: _anchor(m["study"]) for m in others if m["files"]}
    tables = [f for m in main for f in m["files"] if f.endswith(".md")]
    anchors.update({f: _anchor(f) for f in tables})
    inliner = _Inliner(root, anchors)
    body = [_verdict_section(manifests, inliner)]
    body += [_main_section(m, inliner, "readme_head") for m in main if m["readme_head"]]
    body += [_table_section(f, inliner) for f in tables]
    body += [_study_section(m, inliner) for m in others]
    body += [_main_section(m, inliner, "readme_tail") for m in main if m["readme_tail"]]
    body += [_leftover_figures(m, inliner) for m in main]
    title = f"ident-opt results: {root.resolve().name or root}"
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<title>{html.escape(title)}</title><style>{CSS}</style></head>\n"
        f"<body><main>\n<h1>{html.escape(title)}</h1>\n" + "\n".join(b for b in body if b) + "\n</main></body></html>\n"
    )


def _verdict_section(manifests: list[dict], inliner: _Inliner) -> str:
    """The verdicts, first on the page: each study's, under its title; the folders with their own page linked."""
    parts = ['<section id="verdict" class="verdict">', "<h2>Verdict</h2>"]
    for m in manifests:
        if m.get("verdict"):
            parts += [f"<h3>{html.escape(m['title'])}</h3>", inliner.render(m["verdict"], ".")]
    subpages = [m for m in manifests if m.get("subfolder")]
    for m in subpages:
        parts.append(f"<p>{html.escape(m['study'])}: {inliner.link(m['files'][0], m['title'], '.')}</p>")
    if len(parts) == 2:
        parts.append("<p>No study in this folder states a verdict; its reports follow.</p>")
    return "\n".join([*parts, "</section>"])


def _main_section(m: dict, inliner: _Inliner, key: str) -> str:
    """A main report's README head or tail (its Markdown is relative to the folder)."""
    anchor = f' id="{_anchor(m["study"])}"' if key == "readme_head" else ""
    return f'<section class="study"{anchor}>\n{inliner.render(m[key], ".")}\n</section>'


def _table_section(rel: str, inliner: _Inliner) -> str:
    """One of a main report's Markdown tables (e.g. identify_parameters.md), rendered where its link points."""
    body = inliner.render(inliner.read(rel), str(PurePosixPath(rel).parent))
    return f'<section class="table" id="{_anchor(rel)}">\n{body}\n</section>'


def _study_section(m: dict, inliner: _Inliner) -> str:
    """A study: its title, its main Markdown rendered (a subfolder's README: a link to its page), then its other
    Markdown files, its other figures, links to its other files."""
    first = m["files"][0]
    parts = [f'<section class="study" id="{_anchor(m["study"])}">', f"<h2>{html.escape(m['title'])}</h2>"]
    if m.get("subfolder"):
        parts.append(f"<p>{inliner.link(first, 'its own page', '.')}</p>")
    elif first.endswith(".md"):
        text = inliner.read(first)
        if text.startswith("# "):  # the report's own title stands for the study's
            parts.pop()
        parts.append(inliner.render(text, str(PurePosixPath(first).parent)))
    for other in [f for f in m["files"][1:] if f.endswith(".md")]:  # e.g. compare --against's compare_against.md
        parts.append(inliner.render(inliner.read(other), str(PurePosixPath(other).parent)))
    parts.append(_leftover_figures(m, inliner))
    rest = [f for f in m["files"] if f != first and PurePosixPath(f).suffix.lower() not in IMAGES]
    if rest:
        links = ", ".join(inliner.link(f, PurePosixPath(f).name, ".") for f in rest)
        parts.append(f'<p class="files">Files: {links}</p>')
    return "\n".join([*parts, "</section>"])


def _leftover_figures(m: dict, inliner: _Inliner) -> str:
    """The figures a study wrote that its Markdown neither shows nor links, each with its file name."""
    figures = [f for f in m["files"] if PurePosixPath(f).suffix.lower() in IMAGES and f not in inliner.shown]
    return "\n".join(inliner.figure(f, PurePosixPath(f).name) for f in figures)


def _anchor(name: str) -> str:
    """An element id from a study's (or subfolder's) name: letters, digits, '-' and '_' only."""
    return "study-" + re.sub(r"[^A-Za-z0-9_-]", "_", name)


class _Inliner:
    """Renders Markdown to safe HTML and inlines the folder's figures, each once (later references link to it)."""

    def __init__(self, root: Path, anchors: dict[str, str]) -> None:
        self.root = root.resolve()
        self.anchors = anchors  # a study's main file -> its section's id
        self.shown: dict[str, str] = {}  # figure (relative to root) -> its element id
        self.md = markdown.Markdown(extensions=["tables", "sane_lists"])
        # Raw HTML in Markdown would be markup; names from users must stay text (`<script>` shown, not run).
        self.md.preprocessors.deregister("html_block")
        self.md.inlinePatterns.deregister("html")

    def read(self, rel: str) -> str:
        """A Markdown file of the folder (undecodable bytes replaced)."""
        path = self._inside(rel)
        return path.read_text(encoding="utf-8", errors="replace") if path is not None else ""

    def render(self, text: str, base: str) -> str:
        """`text` (Markdown whose links are relative to the folder's `base`) as HTML: figures inlined, links to
        figures and to reports on this page made in-page, wide tables scrollable."""
        out = self.md.reset().convert(text)
        out = re.sub(r'<img alt="([^"]*)" src="([^"]*)" */?>', lambda g: self._img(g[1], g[2], base), out)
        out = re.sub(r'<a href="([^"]*)">(.*?)</a>', lambda g: self._a(g[1], g[2], base), out, flags=re.S)
        return out.replace("<table>", '<div class="scroll"><table>').replace("</table>", "</table></div>")

    def figure(self, rel: str, caption: str, alt: str | None = None) -> str:
        """A <figure> with the file inlined as a data URI (once; after that a link to it), or a note if absent."""
        if rel in self.shown:
            return f'<p><a href="#{self.shown[rel]}">{html.escape(caption)}</a> (shown above)</p>'
        path = self._inside(rel)
        if path is None or PurePosixPath(rel).suffix.lower() not in IMAGES:
            return f'<p class="missing">Figure not found: {html.escape(rel)}</p>'
        self.shown[rel] = f"fig-{len(self.shown) + 1}"
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        src = f"data:{IMAGES[path.suffix.lower()]};base64,{data}"
        return (
            f'<figure id="{self.shown[rel]}"><img alt="{html.escape(alt or caption)}" src="{src}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )

    def link(self, target: str, label: str, base: str) -> str:
        """A link to a file of the folder by its name (`label`, escaped here)."""
        return self._a(html.escape(target), html.escape(label), base)

    def _img(self, alt: str, src: str, base: str) -> str:
        rel = self._rel(html.unescape(src), base)
        return self.figure(rel, html.unescape(alt)) if rel else f'<span class="missing">[{alt}]</span>'

    def _a(self, href: str, label: str, base: str) -> str:
        """A link from rendered Markdown (`href`, `label` already escaped): a figure inlined, a report on this page
        made in-page, a subfolder's README turned into its page; other schemes than `SCHEMES` dropped."""
        target = html.unescape(href)
        scheme = urlsplit(target).scheme.lower()
        if scheme in SCHEMES or target.startswith("#"):
            return f'<a href="{href}">{label}</a>'
        rel = self._rel(target, base) if not scheme else None
        if rel is None:
            return label
        if PurePosixPath(rel).suffix.lower() in IMAGES:
            return self.figure(rel, html.unescape(re.sub(r"<[^>]+>", "", label)))
        if rel in self.anchors:
            return f'<a href="#{self.anchors[rel]}">{label}</a>'
        page = PurePosixPath(rel).with_name(PAGE).as_posix()
        if PurePosixPath(rel).name == "README.md" and (self.root / page).is_file():
            rel = page
        return f'<a href="{html.escape(rel)}">{label}</a>'

    def _rel(self, target: str, base: str) -> str | None:
        """`target` (relative to `base`) as a path relative to the folder, or None when it leaves the folder."""
        path = unquote(urlsplit(target).path)
        if not path or path.startswith("/"):
            return None
        parts: list[str] = []
        for part in PurePosixPath(base, path).parts:
            if part == "..":
                if not parts:
                    return None
                parts.pop()
            elif part != ".":
                parts.append(part)
        return "/".join(parts) or None

    def _inside(self, rel: str) -> Path | None:
        """The file `rel` of the folder, when it is one and (links resolved) inside the folder."""
        path = (self.root / rel).resolve()
        return path if path.is_file() and path.is_relative_to(self.root) else None
