"""Length units of a scene. Coefficients (mua, mus) are always in cm^-1."""

UNIT_CM = {"m": 100.0, "cm": 1.0, "mm": 0.1}


def unit_cm(unit: str) -> float:
    """Length of one scene unit in cm (``"m"`` -> 100, ``"cm"`` -> 1, ``"mm"`` -> 0.1)."""
    try:
        return UNIT_CM[unit]
    except (KeyError, TypeError):
        raise ValueError(f"scene.unit = {unit!r} must be one of 'm', 'cm', 'mm'") from None
