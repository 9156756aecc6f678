"""The units strains are shown in (tables, figures); files keep them dimensionless."""

from __future__ import annotations

#: ``--strain-units`` name: (factor from the dimensionless strain, label drawn).
STRAIN_UNITS = {"1": (1.0, "1"), "%": (100.0, "%"), "microstrain": (1e6, "µε")}


def strain_scale(units) -> tuple[float, str]:
    """``(factor, label)`` of a strain unit: ``"1"`` (dimensionless), ``"%"`` or
    ``"microstrain"`` (µε); ``True`` and ``False`` mean microstrain and dimensionless,
    as the figures' ``microstrain=`` flag did.

    Examples
    --------
    >>> strain_scale("%")
    (100.0, '%')
    """
    if units is True or units is False:
        units = "microstrain" if units else "1"
    if not isinstance(units, str) or units not in STRAIN_UNITS:
        raise ValueError(f"strain units must be one of {', '.join(map(repr, STRAIN_UNITS))}"
                         f", got {units!r}")
    return STRAIN_UNITS[units]
