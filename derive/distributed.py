"""Forces of a tilted array from the Inductrack circuit model (beyond the paper's eq 3 shortcut).

The paper applies eq 3 at the centre of each array face, with the face-centre gap. A rolled or
pitched array has a gap that varies across its width and along its length; this module sums the
circuit model over the face instead, in closed form.

Assumptions (stated in the report too):

1. The field of the array at a track point is the untilted array's field at the local gap,
   B(s, t) = B0 exp(-k g(s, t)) (tilts are small against the wavelength: the field lines of a
   face tilted by a few degrees are those of a flat face at the local distance).
2. The pose is exact, so the gap is linear across the face: g(s, t) = g_c + alpha s + beta t,
   with s across the width (unit e_s) and t along the length (unit e_t) in the face plane,
   alpha = n . R e_s and beta = n . R e_t (n: the track normal; R: the body's rotation).
3. A transverse circuit's current follows the flux through it, the field integrated across its
   width at the local gaps: I ~ int B ds. Its force is that current times the local field along
   it, dF = I B(s) ds, so a circuit carries (int B ds)^2 where eq 3 has (B0 w exp(-k g))^2.
4. The array covers N circuits at pitch p along its length (length N p), circuit j at
   t_j = (j - (N - 1)/2) p, each at its own gap. All circuits see the face centre's speed (the
   speed varies across the face by omega x r, a second-order effect on the frequency factor).
5. Lift and drag of each circuit share the distribution (drag = lift R / (omega L), eq 3 and
   ref [5]), so both act at the same point of the face.

Results (x = k alpha w / 2, y = k beta p):

    F_array = N F_eq3(g_c) sinhc(x)^2 sinhc(N y) / sinhc(y),        sinhc(u) = sinh(u) / u
    point of action: face centre - (w/2) L(x) e_s - (p/2) (N L(N y) - L(y)) e_t,
                     L(u) = coth(u) - 1/u (the Langevin function)

The circuits' sum is a geometric series, sum_j exp(-2 y (j - (N-1)/2)) = sinh(N y) / sinh(y), and
the centroid is -(1/(2k)) d/dbeta of its logarithm; across the width, int exp(-k alpha s) ds =
w sinhc(x) and its centroid -(1/k) d/dalpha ln(w sinhc(x)) = -(w/2) L(x). At zero tilt the
factor is 1 and the point is the face centre: eq 3 times N at the centre, the paper's model.

sinhc and L have removable singularities at 0; below |u| = SERIES_BELOW they are evaluated by
their Taylor series (relative truncation error under 1e-16 there; above it the closed form of L
loses about 1/(3 u^2) ulps to cancellation, 16 at the switch).
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

__all__ = ["SERIES_BELOW", "DistributedLoad", "distributed_load", "face_axes", "langevin",
           "sinhc"]

SERIES_BELOW = 0.25  # |u| below which sinhc and L use their series


def sinhc(u: sp.Expr) -> sp.Expr:
    """sinh(u)/u, with its value 1 at u = 0 (series to u^10 below SERIES_BELOW)."""
    series = 1 + u**2 / 6 + u**4 / 120 + u**6 / 5040 + u**8 / 362880 + u**10 / 39916800
    return sp.Piecewise((series, sp.Abs(u) < SERIES_BELOW), (sp.sinh(u) / u, True))


def langevin(u: sp.Expr) -> sp.Expr:
    """L(u) = coth(u) - 1/u, with L(0) = 0 (series to u^13 below SERIES_BELOW).

    The centroid of exp(-2u s/w) over s in [-w/2, w/2] sits at -(w/2) L(u)."""
    series = (u / 3 - u**3 / 45 + 2 * u**5 / 945 - u**7 / 4725 + 2 * u**9 / 93555
              - 1382 * u**11 / 638512875 + 4 * u**13 / 18243225)
    return sp.Piecewise((series, sp.Abs(u) < SERIES_BELOW), (1 / sp.tanh(u) - 1 / u, True))


def face_axes(normal: sp.Matrix) -> tuple[sp.Matrix, sp.Matrix]:
    """(e_s, e_t): unit vectors of an array face, across its width and along its length.

    e_t is the body x axis (the direction of travel) projected onto the face; e_s = n x e_t.
    For the paper's arrays (normals in the body y-z plane) e_t = x."""
    ex = sp.Matrix([1, 0, 0])
    e_t = ex - normal[0] * normal
    e_t = e_t / sp.sqrt(1 - normal[0] ** 2)
    return normal.cross(e_t), e_t


@dataclass(frozen=True)
class DistributedLoad:
    """One array's load summed over its face (see the module docstring).

    ``factor`` multiplies N times eq 3 at the face-centre gap; ``offset`` is the point of action
    relative to the face centre, body axes; ``closest_gap`` is the gap of the face's closest
    corner (what touches the track first); ``alpha``/``beta`` are the gap's slopes across and
    along the face."""

    factor: sp.Expr
    offset: sp.Matrix
    closest_gap: sp.Expr
    alpha: sp.Expr
    beta: sp.Expr


def distributed_load(normal: sp.Matrix, R: sp.Matrix, centre_gap: sp.Expr, wavenumber: sp.Expr,
                     width: sp.Expr, pitch: sp.Expr, circuits: sp.Expr) -> DistributedLoad:
    """The circuit model summed over a tilted face (assumptions 1-5 of the module docstring).

    ``normal`` is the array's unit normal in body axes (the track normal at the design pose),
    ``R`` the body-to-inertial rotation, ``centre_gap`` the exact face-centre gap."""
    e_s, e_t = face_axes(normal)
    alpha = (normal.T * R * e_s)[0]
    beta = (normal.T * R * e_t)[0]
    x = wavenumber * alpha * width / 2
    y = wavenumber * beta * pitch
    factor = sinhc(x) ** 2 * sinhc(circuits * y) / sinhc(y)
    offset = (-(width / 2) * langevin(x) * e_s
              - (pitch / 2) * (circuits * langevin(circuits * y) - langevin(y)) * e_t)
    closest = centre_gap - sp.Abs(alpha) * width / 2 - sp.Abs(beta) * circuits * pitch / 2
    return DistributedLoad(factor, offset, closest, alpha, beta)
