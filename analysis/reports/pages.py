"""The small HTML vocabulary of the generated reports: one style sheet, Markdown tables as HTML, figures.

Pages are self-contained folders: relative links only, no scripts, no network.
"""

from __future__ import annotations

import html


def html_table(rows_md: str) -> str:
    """The Markdown tables of :func:`~.tables.table_markdown` as HTML."""
    out, in_table = [], False
    for line in rows_md.splitlines():
        if line.startswith("**"):
            out.append(f"<h3>{html.escape(line.strip('*'))}</h3>")
        elif line.startswith("|---"):
            continue
        elif line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            tag = "td" if in_table else "th"
            if not in_table:
                out.append("<table>")
                in_table = True
            out.append("<tr>" + "".join(f"<{tag}>{html.escape(c)}</{tag}>" for c in cells) + "</tr>")
        elif in_table:
            out.append("</table>")
            in_table = False
    if in_table:
        out.append("</table>")
    return "\n".join(out)


#: style of every generated page (no external resources)
CSS = (
    "body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
    "table{border-collapse:collapse;font-size:12px;margin-bottom:1em}"
    "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}"
    "img{max-width:100%;border:1px solid #ddd;margin:4px 0}figcaption{font-size:12px;color:#444}"
)


def figure_html(name: str, caption: str) -> str:
    """A figure saved as ``name``.png/.pdf beside the page: the PNG shown, the PDF linked."""
    return (
        f'<figure><img src="{html.escape(name)}.png" alt="{html.escape(name)}">'
        f'<figcaption>{html.escape(caption)} (<a href="{html.escape(name)}.pdf">PDF</a>)</figcaption></figure>'
    )
