"""A self-contained HTML document: sections with navigation, tables, inline figures, print styles.

Everything a page shows travels inside it: figures as data URIs (PNG) or inline SVG, one
stylesheet in the head, no script, nothing fetched. It reads well printed to PDF from a
browser: the navigation is hidden and each section of class ``page`` starts a page.
"""

from __future__ import annotations

import base64
import datetime as dt
import hashlib
import io
import re
import subprocess
from collections.abc import Iterable, Sequence
from html import escape
from pathlib import Path

from infra.provenance import tool_text

STYLE = """
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color: #1d2329; margin: 0; }
header { background: #14324f; color: #fff; padding: 18px 32px; }
header h1 { margin: 0 0 4px; font-size: 22px; }
header p { margin: 0; opacity: 0.85; }
nav { position: sticky; top: 0; background: #eef2f6; padding: 8px 32px; border-bottom: 1px solid #cfd8e2; z-index: 1; }
nav a { margin-right: 14px; color: #14324f; text-decoration: none; font-weight: 600; }
nav .cases { margin-top: 4px; font-size: 12px; }
nav .cases a { font-weight: 500; white-space: nowrap; }
nav small { color: #4a5560; }
table.signoff td { min-width: 150px; height: 26px; }
main { padding: 8px 32px 40px; max-width: 1200px; }
section { margin-top: 28px; }
h2 { border-bottom: 2px solid #14324f; padding-bottom: 4px; font-size: 19px; }
h3 { font-size: 16px; margin-bottom: 6px; }
table { border-collapse: collapse; margin: 8px 0 14px; font-size: 13px; }
th, td { border: 1px solid #cfd8e2; padding: 3px 8px; text-align: right; vertical-align: top; }
th { background: #eef2f6; }
td.l, th.l { text-align: left; }
.pass { color: #11623a; font-weight: 700; }
.fail { color: #a4161a; font-weight: 700; }
.verdict { font-size: 18px; font-weight: 600; padding: 10px 14px; border-left: 6px solid #14324f; background: #f5f8fb; }
figure { margin: 10px 0 18px; }
figure img, figure svg { max-width: 100%; height: auto; border: 1px solid #e2e8ee; }
figcaption { font-size: 12px; color: #4a5560; }
pre { background: #f5f8fb; padding: 10px; overflow-x: auto; font-size: 12px; }
dl { display: grid; grid-template-columns: max-content auto; gap: 2px 14px; }
dt { font-weight: 600; }
dd { margin: 0; }
.note { color: #4a5560; font-size: 13px; }
@media print {
  nav { display: none; }
  section.page { page-break-before: always; }
  header { background: none; color: #000; border-bottom: 2px solid #000; }
  a { color: inherit; text-decoration: none; }
}
"""


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def sha256_files(paths: Iterable[Path]) -> str:
    """One hash of several files: of their names and contents, in name order."""
    h = hashlib.sha256()
    for p in sorted(paths, key=lambda p: p.name):
        h.update(p.name.encode() + b"\0" + bytes.fromhex(sha256_file(p)))
    return h.hexdigest()


def png(path: Path, alt: str, caption: str = "") -> str:
    """A PNG file as an inline figure (data URI)."""
    data = base64.b64encode(Path(path).read_bytes()).decode()
    cap = f"<figcaption>{escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img alt="{escape(alt)}" src="data:image/png;base64,{data}">{cap}</figure>'


def svg(fig, caption: str = "") -> str:
    """A matplotlib figure as inline SVG."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    text = buf.getvalue()
    text = text[text.index("<svg") :]
    cap = f"<figcaption>{escape(caption)}</figcaption>" if caption else ""
    return f"<figure>{text}{cap}</figure>"


def fmt(v, digits: int = 4) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return escape(str(v))


def _text(c) -> bool:
    """A cell of words (left-aligned) rather than a number."""
    if not isinstance(c, str):
        return False
    try:
        float(c.replace("x", "").replace("%", "").split("&")[0])
        return False
    except ValueError:
        return not c.startswith("<span")


def table(header: Sequence[str], rows: Iterable[Sequence], left: int = 1, raw: bool = False) -> str:
    """An HTML table; the first ``left`` columns, and cells of words, left-aligned. Cells are
    escaped unless ``raw``."""
    th = "".join(f'<th class="{"l" if i < left else ""}">{escape(h)}</th>' for i, h in enumerate(header))
    body = []
    for row in rows:
        cells = "".join(
            f'<td class="{"l" if i < left or _text(c) else ""}">{c if raw else fmt(c)}</td>' for i, c in enumerate(row)
        )
        body.append(f"<tr>{cells}</tr>")
    return f"<table><thead><tr>{th}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def definitions(items: Iterable[tuple[str, object]]) -> str:
    return "<dl>" + "".join(f"<dt>{escape(k)}</dt><dd>{fmt(v)}</dd>" for k, v in items) + "</dl>"


def anchor(text: str) -> str:
    """A section id (and link target) from any text: letters, digits, ``-``, ``_`` and ``.`` kept."""
    return re.sub(r"[^A-Za-z0-9_.-]", "-", text)


def section(anchor: str, title: str, body: str, page: bool = False) -> tuple[str, str, str]:
    return (
        anchor,
        title,
        f'<section id="{anchor}"{" class=page" if page else ""}><h2>{escape(title)}</h2>{body}</section>',
    )


def document(
    title: str,
    subtitle: str,
    sections: Sequence[tuple[str, str, str]],
    nav_extra: str = "",
    nav_skip: Iterable[str] = (),
) -> str:
    """The page: a header, the navigation (each section but those of ``nav_skip``'s anchors, then
    ``nav_extra``'s raw HTML) and the sections."""
    skip = set(nav_skip)
    nav = "".join(f'<a href="#{a}">{escape(t)}</a>' for a, t, _ in sections if a not in skip) + nav_extra
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{escape(title)}</title><style>{STYLE}</style></head><body>"
        f"<header><h1>{escape(title)}</h1><p>{escape(subtitle)}</p></header><nav>{nav}</nav><main>"
        + "".join(s for _, _, s in sections)
        + "</main></body></html>\n"
    )


def write(path: Path, text: str) -> Path:
    """Write atomically: a report being refreshed is never seen half written."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path


def now() -> str:
    return dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def software_commit() -> str:
    """The git commit of this software if it runs from its own source checkout (the work tree whose
    top holds these packages), "" otherwise: an installed copy reports its version alone, never the
    commit of a repository it happens to sit in."""
    here = Path(__file__).resolve().parents[2]  # the folder holding the campaign package
    try:
        out = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "--show-toplevel", "HEAD"], capture_output=True, text=True, timeout=5
        )
    except (OSError, subprocess.SubprocessError):
        return ""
    lines = out.stdout.split()
    if out.returncode != 0 or len(lines) != 2 or Path(lines[0]).resolve() != here:
        return ""
    return lines[1]


def traceability(folder: Path, man: dict | None, extra: dict[str, Path]) -> str:
    """The hashes of the settings, data and results files, the software versions and commit."""
    rows = []
    if man is not None:
        s = man.get("settings", {})
        for key in ("matrix", "aircraft", "effects", "instruments"):
            if s.get(key) is not None:
                rows.append((key, s.get(key), s.get(f"{key}_sha256", "")))
        logs = sorted(folder.glob("*.parquet"))
        rows.append(("flight logs", f"{len(logs)} Parquet files", sha256_files(logs) if logs else ""))
    for name, path in extra.items():
        if path.exists():
            rows.append((name, path.relative_to(folder) if path.is_relative_to(folder) else path, sha256_file(path)))
    versions = {"report written by": tool_text()}
    if man and man.get("tool"):
        versions["campaign flown by"] = f"{man['tool']['name']} {man['tool']['version']}"
    versions.update(man.get("versions", {}) if man else {})
    commit = software_commit()
    if commit:
        versions["software commit"] = commit
    return (
        table(["item", "file", "sha256"], rows, left=2)
        + definitions(versions.items())
        + f'<p class="note">report written {now()}</p>'
    )
