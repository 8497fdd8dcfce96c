# SPDX-License-Identifier: MIT
"""The add-on's one error for bad user input (no bpy)."""


class InputError(ValueError):
    """Bad user input; the message names the object (or scene) and the field."""
