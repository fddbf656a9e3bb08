"""The one door from bgc's text to modelDescription.xml: XML 1.0 holds only TAB, LF, CR and
the characters from U+0020 up (less the surrogates and U+FFFE, U+FFFF), in element text and
attribute values alike, and no escape can put another in. Every text of the description
passes :func:`xml_text` (through :func:`clean_tree`, once, just before the tree is written):
any other character becomes U+FFFD, so every written FMU parses.
"""
from __future__ import annotations

import re

#: What XML 1.0 cannot hold (section 2.2, Char).
_BAD = re.compile("[^\t\n\r\u0020-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def xml_text(s: str) -> str:
    """``s`` with every character XML 1.0 cannot hold replaced by U+FFFD."""
    return _BAD.sub("\ufffd", s)


def clean_tree(root) -> None:
    """Every tag, attribute and text of an ElementTree made XML 1.0 text, in place."""
    for el in root.iter():
        if el.text:
            el.text = xml_text(el.text)
        if el.tail:
            el.tail = xml_text(el.tail)
        for k, v in list(el.attrib.items()):
            el.attrib[k] = xml_text(v)
