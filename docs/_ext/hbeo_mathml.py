"""Sphinx's HTML math as MathML, written at build time with latex2mathml (the converter ``hbeo book`` uses:
:func:`hbeo.report.book._mathml`), so that no page loads MathJax or anything else from the network.

``html_math_renderer = "mathml"`` in ``conf.py`` selects it. Inline math (``$...$``, ``:math:``) becomes inline
MathML, display math (``$$...$$``, ``.. math::``) block MathML with its equation number; what latex2mathml
cannot read is shown as its TeX source in a ``<code>`` element, never an error.
"""
from __future__ import annotations

import html

from docutils import nodes


def _mathml(tex: str, display: str) -> str:
    from hbeo.report.book import _mathml as convert
    return convert(tex, display)


def visit_math(self, node) -> None:
    self.body.append(f'<span class="math notranslate">{_mathml(node.astext(), "inline")}</span>')
    raise nodes.SkipNode


def visit_displaymath(self, node) -> None:
    latex = node.astext()
    parts = [latex] if node.get("nowrap") else [p for p in latex.split("\n\n") if p.strip()]
    self.body.append(self.starttag(node, "div", CLASS="math notranslate"))
    if node.get("number"):
        from sphinx.util.math import get_node_equation_number
        self.body.append(f'<span class="eqno">({html.escape(str(get_node_equation_number(self, node)))})</span>')
    for part in parts:
        self.body.append(_mathml(part, "block"))
    self.body.append("</div>\n")
    raise nodes.SkipNode


def setup(app):
    app.add_html_math_renderer("mathml", (visit_math, None), (visit_displaymath, None))
    return {"parallel_read_safe": True, "parallel_write_safe": True}
