"""MkDocs hook: a pipe inside a code span in a table cell.

GitHub needs it written `\\|` (or it splits the cell there); Python-Markdown already
keeps pipes inside code spans out of the split and would show the backslash.  On
table rows only, drop the backslash before a pipe inside a code span, so that the
same pages read right on GitHub and in the built site.
"""

import re

_CODE_SPAN = re.compile(r"(`+)(.+?)\1")


def _unescape(match: re.Match[str]) -> str:
    return match.group(0).replace("\\|", "|")


def on_page_markdown(markdown: str, **kwargs: object) -> str:
    lines = markdown.split("\n")
    for i, line in enumerate(lines):
        if line.lstrip().startswith("|"):
            lines[i] = _CODE_SPAN.sub(_unescape, line)
    return "\n".join(lines)
