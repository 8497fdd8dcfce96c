# SPDX-License-Identifier: MIT
"""Small helpers without bpy."""


def wrap_text(text, width):
    """Split ``text`` into lines of at most ``width`` characters (panel labels do not wrap)."""
    lines, line = [], ""
    for word in str(text).split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}" if line else word
    if line:
        lines.append(line)
    return lines
