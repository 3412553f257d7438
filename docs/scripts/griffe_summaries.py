"""A griffe extension (`mkdocs.yml`): the API reference's summary tables show each
object's first *sentence*, not its docstring's first line. The summary tables take the
first line; this puts the whole first sentence on it by joining the lines it was wrapped
over (Markdown renders a paragraph the same however its lines are wrapped)."""

from __future__ import annotations

import re

import griffe

# The end of a sentence: a full stop, outside backticks, before a space and a capital,
# a backtick or an opening bracket, or at the end of the paragraph.
_END = re.compile(r"[.!?](?=\s+[A-Z`(*\[])")


def first_sentence_first(text: str) -> str:
    """`text` (a docstring) with its first sentence joined onto its first line."""
    lines = text.split("\n")
    count = 0
    while count < len(lines) and lines[count].strip():
        count += 1
    if count < 2:
        return text
    paragraph = " ".join(line.strip() for line in lines[:count])
    end = None
    inside = False
    for i, ch in enumerate(paragraph):
        if ch == "`":
            inside = not inside
        elif not inside and _END.match(paragraph, i):
            end = i + 1
            break
    if end is None:
        head, rest = paragraph, ""
    else:
        head, rest = paragraph[:end], paragraph[end:].strip()
    return "\n".join([head, *([rest] if rest else []), *lines[count:]])


class WholeSentenceSummaries(griffe.Extension):
    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = first_sentence_first(obj.docstring.value)
