"""MkDocs hook: the docstrings' Sphinx roles (``:class:`Pose```,
``:func:`~mutloc.errors.X```) shown as plain code in the API pages,
``~`` keeping only the last name, as Sphinx does."""

import re

_ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|exc|obj|py:\w+):<code>(~?)([^<]*)</code>")


def _code(m: re.Match) -> str:
    name = m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2)
    return f"<code>{name}</code>"


def on_post_page(output: str, **kwargs) -> str:
    return _ROLE.sub(_code, output)
