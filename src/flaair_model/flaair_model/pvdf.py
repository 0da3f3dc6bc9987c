"""Composite-beam PVDF charge model (paper eqs. charge, zna, strain, combined, chargeamp).

Pure functions over frozen dataclasses; numpy only. SI units throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "VACUUM_PERMITTIVITY_F_PER_M",
    "PvdfMaterial",
    "SensorBeam",
    "charge_per_tip_displacement_c_per_m",
    "pitch_volts_per_rad",
    "stroke_volts_per_rad",
    "volts_per_tip_displacement_v_per_m",
]


VACUUM_PERMITTIVITY_F_PER_M = 8.854187817e-12


@dataclass(frozen=True)
class PvdfMaterial:
    """Material of the PVDF sensing film (paper Table 1)."""

    g31_v_m_per_n: float
    relative_permittivity: float
    modulus_pa: float
    thickness_m: float


@dataclass(frozen=True)
class SensorBeam:
    """One two-layer composite beam (backing + PVDF) and its charge amplifier."""

    area_m2: float
    backing_thickness_m: float
    length_m: float
    backing_modulus_pa: float
    charge_amp_gain_per_f: float


def charge_per_tip_displacement_c_per_m(material: PvdfMaterial, beam: SensorBeam) -> float:
    """Magnitude S of the charge per unit tip displacement, Q = -S * delta.

    Parameters
    ----------
    material, beam
        Film material and beam geometry.

    Returns
    -------
    float
        S in C/m (paper eq. combined).
    """
    tb, tp = beam.backing_thickness_m, material.thickness_m
    eb, ep = beam.backing_modulus_pa, material.modulus_pa
    strain_per_displacement = eb * tb * (tb + tp) / ((eb * tb + ep * tp) * beam.length_m**2)
    return (
        material.g31_v_m_per_n
        * VACUUM_PERMITTIVITY_F_PER_M
        * material.relative_permittivity
        * ep
        * beam.area_m2
        * strain_per_displacement
    )


def volts_per_tip_displacement_v_per_m(material: PvdfMaterial, beam: SensorBeam) -> float:
    """Charge-amplifier output change per metre of tip
    displacement (signed: V = V_HREF - k*delta).
    """
    return -beam.charge_amp_gain_per_f * charge_per_tip_displacement_c_per_m(material, beam)


def stroke_volts_per_rad(
    material: PvdfMaterial, beam: SensorBeam, transmission_ratio_rad_per_m: float
) -> float:
    """Actuator-sensor output per radian of stroke, with delta_a = phi / T_r."""
    return volts_per_tip_displacement_v_per_m(material, beam) / transmission_ratio_rad_per_m


def pitch_volts_per_rad(material: PvdfMaterial, beam: SensorBeam) -> float:
    """Hinge-sensor output per radian of pitch, with constant-curvature delta_w = psi * l / 2."""
    return volts_per_tip_displacement_v_per_m(material, beam) * beam.length_m / 2.0
