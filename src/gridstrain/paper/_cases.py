"""The cases of the paper's experiment (the vibrations' standard deviations), the quantities
it measures, and how a record of them is looked up.
"""

from __future__ import annotations

from .dataset import (
    vibration_cases,
)

#: Quantities whose RMSE is measured, with their unit.
QUANTITIES = {
    "phi1": "rad", "phi2": "rad", "phi1_corrected": "rad", "phi2_corrected": "rad",
    "dphi1_dx": "rad/px", "dphi1_dy": "rad/px", "dphi2_dx": "rad/px", "dphi2_dy": "rad/px",
    "image": "grey levels",
}


_DERIVATIVES = ("dphi1_dx", "dphi1_dy", "dphi2_dx", "dphi2_dy")


#: The vibration case added to the paper's four: (sigma_alpha, sigma_beta), px.
LARGE_VIBRATION = (0.5, 0.5)


def _all_cases() -> dict[int, tuple[float, float]]:
    """The paper's four cases and case 5, :data:`LARGE_VIBRATION`."""
    return {**vibration_cases(), 5: LARGE_VIBRATION}


def _get(records, method, case, q):
    rs = sorted((r for r in records if r["method"] == method and r["case"] == case
                 and r["quantity"] == q), key=lambda r: r["T"])
    return [r["T"] for r in rs], [r["rmse"] for r in rs], [r["theory"] for r in rs]
