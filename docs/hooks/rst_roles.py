"""MkDocs hook: the docstrings' Sphinx roles (``:class:`Pose```,
``:func:`~mutloc.errors.X```) shown as plain code in the API pages,
``~`` keeping only the last name, as Sphinx does; the docstrings' mentions
of "the SPEC" made links to the manual's pages."""

import logging
import re

log = logging.getLogger("mkdocs.hooks.rst_roles")

_ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|exc|obj|py:\w+):<code>(~?)([^<]*)</code>")


def _code(m: re.Match) -> str:
    name = m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2)
    return f"<code>{name}</code>"


def on_post_page(output: str, **kwargs) -> str:
    return _ROLE.sub(_code, output)


# The docstrings name the file formats' contract "the SPEC", a document users do not have: in the
# manual each such mention becomes a link to the page that holds it.  A mention no rule below
# rewrites is a build warning, so `mkdocs build --strict` fails on it.
_SECTIONS = {  # SPEC "Section" -> the manual's page for it
    "Marker calibration": "guides/calibration/",
    "Observation logs": "formats/#observation-logs",
    "Filtered tracking": "guides/tracking/#the-filter",
    "Robots with several cameras": "guides/cameras/",
    "Robots with several cameras, any lens": "guides/cameras/",
    "Live operation": "guides/live/",
    "Teams": "guides/teams/",
    "Experiment results": "formats/",
}
_FORMATS = "formats/"


def _spec_rules(link):
    def section(prefix):
        def sub(m: re.Match) -> str:
            name = " ".join(m.group(1).split())  # a docstring may break the name over lines
            if name not in _SECTIONS:
                return m.group(0)  # left for the warning below
            return f'{prefix}<a href="{link(_SECTIONS[name])}">{name}</a>'
        return sub

    documented = f'<a href="{link(_FORMATS)}">documented</a>'
    formats = f'<a href="{link(_FORMATS)}">Formats</a>'
    return [
        (re.compile(r'\bof SPEC\s+"([^"<]+)"'), section("described in ")),
        (re.compile(r'\bSPEC\s+"([^"<]+)"'), section("see ")),
        (re.compile(r"\bof SPEC\b"), f"in {formats}"),
        (re.compile(r"(?<=<p>)SPEC's\b"), f"The {documented}"),
        (re.compile(r"\b([Tt]he) SPEC's\b"), rf"\1 {documented}"),
        (re.compile(r"\bSPEC's\b"), f"the {documented}"),
        (re.compile(r"\bSPEC order\b"), f"the {documented} order"),
    ]


def on_page_content(html: str, page, config, files) -> str:
    from mkdocs.utils import get_relative_url

    if "SPEC" not in html:
        return html
    for pattern, repl in _spec_rules(lambda target: get_relative_url(target, page.url)):
        html = pattern.sub(repl, html)
    for m in re.finditer(r".{0,60}\bSPEC\b.{0,60}", html):
        log.warning("%s: 'SPEC' (not shipped) left in the page: ...%s...", page.file.src_path, m.group(0))
    return html
