"""The one module that keeps file data out of a page's markup, for every page (the report's, the people page, any to
come): its template's styles start with ``page_assets/base.css``, its first script is ``page_assets/kit.js`` (the
error handler that says why a page could not be built, and the helpers every string and number from a file goes
through: text nodes, ``esc``, ``num``, ``int_``), and the data is inlined as JSON that no string can end
(:func:`render`).

A template holds three marks: ``/*__PAGE_CSS__*/`` inside its ``<style>``, ``<!--__PAGE_KIT__-->`` where the kit's
script goes (before the data and the page's own script), and ``/*__DATA__*/null`` inside its data script. The page's
element for errors carries ``data-page-errors``.
"""
from __future__ import annotations

import base64
import json
from importlib import resources
from typing import Any

import numpy as np

#: Characters escaped in the inline JSON: none of them can then end the script element, open a comment or a tag, or
#: end a line of script (JSON.parse reads the escapes back).
INLINE_ESCAPES = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}
MARKS = ("/*__PAGE_CSS__*/", "<!--__PAGE_KIT__-->", "/*__DATA__*/null")


def inline_json(data: Any) -> str:
    """``data`` as JSON that can stand inside a ``<script>`` element (:data:`INLINE_ESCAPES`; NaN refused)."""
    text = json.dumps(data, separators=(",", ":"), allow_nan=False)
    for char, escape in INLINE_ESCAPES.items():
        text = text.replace(char, escape)
    return text


def pack_b64(a: np.ndarray, dtype: str) -> str:
    """An array as base64 of its bytes in ``dtype`` (e.g. ``"<i2"``, little-endian: the pages read them with typed
    arrays)."""
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode("ascii")


def _shared(name: str) -> str:
    return resources.files("dome_calib").joinpath("page_assets", name).read_text(encoding="utf-8")


def render(package: str, template: str, data: Any) -> str:
    """The page: ``package``'s ``template`` with the shared styles, the kit's script and ``data`` inline. Raises
    ValueError when the template lacks one of the marks (a page that would skip the shared escaping)."""
    page = resources.files(package).joinpath(template).read_text(encoding="utf-8")
    missing = [m for m in MARKS if page.count(m) != 1]
    if missing:
        raise ValueError(f"{package}/{template}: expected each of {', '.join(MARKS)} once (missing or repeated: "
                         f"{', '.join(missing)})")
    page = page.replace(MARKS[0], _shared("base.css"), 1)
    page = page.replace(MARKS[1], "<script>\n" + _shared("kit.js") + "</script>", 1)
    return page.replace(MARKS[2], inline_json(data), 1)
