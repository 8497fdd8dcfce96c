# SPDX-License-Identifier: MIT
"""Small helpers without bpy."""


def wrap_text(text, width):
    """Split ``text`` into lines of at most ``width`` characters (panel labels do not wrap); a
    word longer than ``width`` (a folder path) is split across lines, never cut."""
    lines, line = [], ""
    for word in str(text).split():
        while len(word) > width:
            if line:
                lines.append(line)
                line = ""
            lines.append(word[:width])
            word = word[width:]
        if not word:
            continue
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}" if line else word
    if line:
        lines.append(line)
    return lines
