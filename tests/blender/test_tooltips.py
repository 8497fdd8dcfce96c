# SPDX-License-Identifier: MIT
"""Issue 36, defect 8: every property the panels show has a tooltip, and every number's tooltip
(or its label) says its unit."""

from endophoton_addon import preferences, properties

# Words that state a number's unit (or that it has none).
UNIT_WORDS = (
    "cm⁻¹",
    "mm",
    "scene length units",
    "degrees",
    "pixels",
    "count",
    "integer",
    "unitless",
    "rank",
    "powers of ten",
    "0-1",
    "%",
    "linear RGB",
)
INTERNAL = {
    "rna_type",
    "name",
    "bl_idname",
    "is_rig",
    "active_fluorophore",
    "scene_report",
    "legend_header",
    "result_collection",
    "medium",
    "fluorophores",
    "legend",
    "sweep",
}


def _properties():
    for cls in properties.CLASSES + preferences.CLASSES:
        for prop in cls.bl_rna.properties:
            if prop.identifier not in INTERNAL and not prop.is_hidden:
                yield cls.__name__, prop


def test_every_property_has_a_tooltip():
    missing = [f"{owner}.{prop.identifier}" for owner, prop in _properties() if not prop.description.strip()]
    assert not missing, missing


def test_every_number_says_its_unit():
    missing = [
        f"{owner}.{prop.identifier}: {prop.description!r}"
        for owner, prop in _properties()
        if prop.type in ("FLOAT", "INT")
        and not any(word in prop.description or word in prop.name for word in UNIT_WORDS)
    ]
    assert not missing, missing
