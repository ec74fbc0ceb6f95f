"""Halbach surface field (eq 4) and the Inductrack lift and drag per circuit (eq 3)."""

from __future__ import annotations

import sympy as sp

__all__ = ["drag_per_circuit", "halbach_surface_field", "lift_per_circuit"]


def halbach_surface_field(remanence: sp.Expr, thickness: sp.Expr, magnets_per_wavelength: sp.Expr,
                          wavenumber: sp.Expr) -> sp.Expr:
    """Eq 4: peak field at the array surface, B0 = Br (1 - exp(-k d)) sin(pi/M) / (pi/M)."""
    x = sp.pi / magnets_per_wavelength
    return remanence * (1 - sp.exp(-wavenumber * thickness)) * sp.sin(x) / x


def lift_per_circuit(B0: sp.Expr, width: sp.Expr, wavenumber: sp.Expr, inductance: sp.Expr,
                     resistance: sp.Expr, gap: sp.Expr, speed: sp.Expr) -> sp.Expr:
    """Eq 3: F = B0^2 w^2 / (2 k L) * 1 / (1 + (R/(omega L))^2) * exp(-2 k gap), omega = k v.

    Written as (omega L)^2 / ((omega L)^2 + R^2), which equals the printed factor for v != 0 and
    stays finite (zero) at v = 0, so the generated code has no division by the speed.
    """
    wl = wavenumber * speed * inductance
    return (B0**2 * width**2 / (2 * wavenumber * inductance)
            * wl**2 / (wl**2 + resistance**2) * sp.exp(-2 * wavenumber * gap))


def drag_per_circuit(B0: sp.Expr, width: sp.Expr, wavenumber: sp.Expr, inductance: sp.Expr,
                     resistance: sp.Expr, gap: sp.Expr, speed: sp.Expr) -> sp.Expr:
    """Magnetic drag per circuit: lift * R / (omega L) (Post's Inductrack theory, ref [5]).

    Written without the 1/omega so that it is finite at v = 0; it opposes the motion.
    """
    wl = wavenumber * speed * inductance
    return (B0**2 * width**2 / (2 * wavenumber * inductance)
            * wl * resistance / (wl**2 + resistance**2) * sp.exp(-2 * wavenumber * gap))
