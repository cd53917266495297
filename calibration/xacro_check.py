"""Tell a xacro program from a URDF that xacro produced.

Most URDFs shipped in ROS description packages are xacro output: the root still declares
``xmlns:xacro=...`` and commented-out ``<xacro:...>`` lines remain, but nothing in them is
left to expand. Only live xacro (an element in the xacro namespace, a ``${...}`` expression
or a ``$(...)`` substitution argument outside comments) means the file must be expanded
first; anything else is a URDF and is loaded as it is.
"""

from __future__ import annotations

import re

_COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)
_LIVE = (
    (re.compile(r"<\s*xacro:([\w.-]+)"), "a <xacro:{0}> element"),
    (re.compile(r"\$\{[^}]*\}?"), "a ${{…}} expression"),
    (re.compile(r"\$\((\w+)"), "a $({0} …) substitution"),
)


def _blank_comments(text: str) -> str:
    """The text with every comment replaced by as many newlines (line numbers stay true)."""
    return _COMMENT.sub(lambda m: "\n" * m.group(0).count("\n"), text)


def live_xacro(text: str) -> str | None:
    """What live xacro the text holds and where (``"a <xacro:macro> element on line 12"``),
    or None for a plain URDF (a declared xacro namespace and xacro in comments are fine)."""
    body = _blank_comments(text)
    found = []
    for pattern, what in _LIVE:
        match = pattern.search(body)
        if match is not None:
            found.append((match.start(), what.format(*match.groups())))
    if not found:
        return None
    start, what = min(found)
    return f"{what} on line {body.count(chr(10), 0, start) + 1}"
