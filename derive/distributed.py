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
their Taylor series (relative truncation error under 1e-16 there). Above it the closed forms
cancel: just past the switch L and L' keep about 4e-14 relative in double and L'', whose terms
cancel about 15/u^4-fold (3840 at the switch), about 5e-12, falling to 2e-14 by |u| = 0.5;
L'' enters only the stiffness and the Jacobians, and a flying carriage's arguments stay under
0.01, on the series. The series are written in
Horner form in u^2 (a product per term, no powers: what the generated C evaluates), and each
closed form also in m = exp(-|u|) (``closed_exp``), so the code generator computes one
exponential per argument for sinhc, L, L' and L'' together instead of a sinh, a tanh and a
cosh each (the closed forms in sinh/tanh stay what SymPy and the lambdified reference use).
"""

from __future__ import annotations

from dataclasses import dataclass

import mpmath
import sympy as sp

__all__ = ["SERIES_BELOW", "distributed_load", "face_axes", "langevin", "langevin_curvature",
           "langevin_slope", "sinhc"]

SERIES_BELOW = 0.25  # |u| below which sinhc, L and L' use their series


def _horner(u: sp.Expr, coefficients: tuple) -> sp.Expr:
    """sum_i c_i u^(2 i) in Horner form in u^2: c_0 + u^2 (c_1 + u^2 (c_2 + ...))."""
    v = u**2
    out = sp.S(coefficients[-1])
    for c in reversed(coefficients[:-1]):
        out = c + v * out
    return out


def _branches(u: sp.Expr, series, closed) -> sp.Expr:
    """series(u) below SERIES_BELOW, else closed(u); the closed form's argument is 1 where the
    series is taken, so neither numpy's select nor CasADi's if_else (which evaluate both
    branches) ever divides by zero."""
    small = sp.Abs(u) < SERIES_BELOW
    safe = sp.Piecewise((sp.S.One, small), (u, True))
    return sp.Piecewise((series(u), small), (closed(safe), True))


class _RemovableSingularity(sp.Function):
    """A real function with a removable singularity at 0, kept opaque in the derivation.

    Opaque, the model's Jacobians stay the size of the point model's (expanded, the two
    branches of each Piecewise multiply through every derivative: 40x the operations). The
    code printers and the CasADi conversion see ``rewrite(Piecewise)``: the Taylor series
    below SERIES_BELOW, the closed form above; evalf uses the closed form in mpmath with the
    working precision raised past its cancellation."""

    removable_singularity = True  # the CasADi conversion rewrites these as their Piecewise
    at_zero: sp.Expr

    @classmethod
    def eval(cls, u):
        if u.is_zero:
            return cls.at_zero
        return None

    @staticmethod
    def series(u: sp.Expr) -> sp.Expr:
        raise NotImplementedError

    @staticmethod
    def closed(u: sp.Expr) -> sp.Expr:
        raise NotImplementedError

    @staticmethod
    def closed_exp(u: sp.Expr, m: sp.Expr) -> sp.Expr:
        """The closed form in u and m standing for exp(-|u|) (|u| >= SERIES_BELOW: no
        cancellation in 1 - m^2 there, and no overflow where a sinh or cosh would not)."""
        raise NotImplementedError

    @staticmethod
    def exact(u: mpmath.mpf) -> mpmath.mpf:
        raise NotImplementedError

    def _eval_is_real(self) -> bool | None:
        return self.args[0].is_real

    def _eval_rewrite_as_Piecewise(self, u: sp.Expr, **_kwargs) -> sp.Expr:
        return _branches(u, self.series, self.closed)

    def _eval_evalf(self, prec: int) -> sp.Float | None:
        u = self.args[0]._eval_evalf(prec)
        if u is None or not u.is_Float:
            return None
        if u == 0:
            return sp.Float(self.at_zero, precision=prec)
        extra = 64 + 2 * max(0, -int(mpmath.floor(mpmath.log(abs(u._to_mpmath(prec)), 2))))
        with mpmath.workprec(prec + extra):
            value = self.exact(u._to_mpmath(prec + extra))
        return sp.Float(value, precision=prec)

    def _numpycode(self, printer) -> str:
        return printer._print(self.rewrite(sp.Piecewise))

    _pythoncode = _mpmathcode = _ccode = _numpycode

    def _latex(self, printer) -> str:
        return rf"\operatorname{{{self.latex_name}}}\left({printer._print(self.args[0])}\right)"


class sinhc(_RemovableSingularity):  # noqa: N801  (a function, named as SymPy's are)
    """sinh(u)/u, 1 at u = 0 (series to u^10 below SERIES_BELOW); sinhc' = sinhc L."""

    at_zero = sp.S.One
    latex_name = "sinhc"

    @staticmethod
    def series(u: sp.Expr) -> sp.Expr:
        # 1 + u^2/6 + u^4/120 + u^6/5040 + u^8/362880 + u^10/39916800
        return _horner(u, (1, sp.Rational(1, 6), sp.Rational(1, 120), sp.Rational(1, 5040),
                           sp.Rational(1, 362880), sp.Rational(1, 39916800)))

    @staticmethod
    def closed(u: sp.Expr) -> sp.Expr:
        return sp.sinh(u) / u

    @staticmethod
    def closed_exp(u: sp.Expr, m: sp.Expr) -> sp.Expr:
        # sinh|u| = (1 - m^2) / (2 m), and sinhc is even
        return (1 - m**2) / (2 * m * sp.Abs(u))

    @staticmethod
    def exact(u: mpmath.mpf) -> mpmath.mpf:
        return mpmath.sinh(u) / u

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        u = self.args[0]
        return sinhc(u) * langevin(u)


class langevin(_RemovableSingularity):  # noqa: N801
    """L(u) = coth(u) - 1/u, 0 at u = 0 (series to u^13 below SERIES_BELOW); L' = langevin_slope.

    The centroid of exp(-2u s/w) over s in [-w/2, w/2] sits at -(w/2) L(u)."""

    at_zero = sp.S.Zero
    latex_name = "L"

    @staticmethod
    def series(u: sp.Expr) -> sp.Expr:
        # u/3 - u^3/45 + 2u^5/945 - u^7/4725 + 2u^9/93555 - 1382u^11/638512875 + 4u^13/18243225
        return u * _horner(u, (sp.Rational(1, 3), sp.Rational(-1, 45), sp.Rational(2, 945),
                               sp.Rational(-1, 4725), sp.Rational(2, 93555),
                               sp.Rational(-1382, 638512875), sp.Rational(4, 18243225)))

    @staticmethod
    def closed(u: sp.Expr) -> sp.Expr:
        return 1 / sp.tanh(u) - 1 / u

    @staticmethod
    def closed_exp(u: sp.Expr, m: sp.Expr) -> sp.Expr:
        # coth|u| = (1 + m^2) / (1 - m^2), and coth is odd
        return sp.sign(u) * (1 + m**2) / (1 - m**2) - 1 / u

    @staticmethod
    def exact(u: mpmath.mpf) -> mpmath.mpf:
        return mpmath.coth(u) - 1 / u

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        return langevin_slope(self.args[0])


class langevin_slope(_RemovableSingularity):  # noqa: N801
    """L'(u) = 1/u^2 - 1/sinh(u)^2, 1/3 at u = 0 (series to u^12 below SERIES_BELOW)."""

    at_zero = sp.Rational(1, 3)
    latex_name = "L'"

    @staticmethod
    def series(u: sp.Expr) -> sp.Expr:
        # 1/3 - u^2/15 + 2u^4/189 - u^6/675 + 2u^8/10395 - 1382u^10/58046625 + 4u^12/1403325
        return _horner(u, (sp.Rational(1, 3), sp.Rational(-1, 15), sp.Rational(2, 189),
                           sp.Rational(-1, 675), sp.Rational(2, 10395),
                           sp.Rational(-1382, 58046625), sp.Rational(4, 1403325)))

    @staticmethod
    def closed(u: sp.Expr) -> sp.Expr:
        return 1 / u**2 - 1 / sp.sinh(u) ** 2

    @staticmethod
    def closed_exp(u: sp.Expr, m: sp.Expr) -> sp.Expr:
        # 1/sinh(u)^2 = 4 m^2 / (1 - m^2)^2
        return 1 / u**2 - 4 * m**2 / (1 - m**2) ** 2

    @staticmethod
    def exact(u: mpmath.mpf) -> mpmath.mpf:
        return 1 / u**2 - 1 / mpmath.sinh(u) ** 2

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        return langevin_curvature(self.args[0])


class langevin_curvature(_RemovableSingularity):  # noqa: N801
    """L''(u) = -2/u^3 + 2 cosh(u)/sinh(u)^3, 0 at u = 0 (series to u^15 below SERIES_BELOW).

    Opaque as the others so that the stiffness (the wrench's derivative, where L' of the
    circuits' lag is differentiated) shares its argument's exponential; its own derivative is
    that of its Piecewise form (nothing in the model differentiates it)."""

    at_zero = sp.S.Zero
    latex_name = "L''"

    @staticmethod
    def series(u: sp.Expr) -> sp.Expr:
        # -2u/15 + 8u^3/189 - 2u^5/225 + 16u^7/10395 - 2764u^9/11609325 + 16u^11/467775
        # - 7234u^13/1550674125 + 1403744u^15/2292899734125
        return u * _horner(u, (sp.Rational(-2, 15), sp.Rational(8, 189), sp.Rational(-2, 225),
                               sp.Rational(16, 10395), sp.Rational(-2764, 11609325),
                               sp.Rational(16, 467775), sp.Rational(-7234, 1550674125),
                               sp.Rational(1403744, 2292899734125)))

    @staticmethod
    def closed(u: sp.Expr) -> sp.Expr:
        return -2 / u**3 + 2 * sp.cosh(u) / sp.sinh(u) ** 3

    @staticmethod
    def closed_exp(u: sp.Expr, m: sp.Expr) -> sp.Expr:
        # cosh(u)/sinh(u)^3 = sign(u) 4 m^2 (1 + m^2) / (1 - m^2)^3
        return -2 / u**3 + 8 * sp.sign(u) * m**2 * (1 + m**2) / (1 - m**2) ** 3

    @staticmethod
    def exact(u: mpmath.mpf) -> mpmath.mpf:
        return -2 / u**3 + 2 * mpmath.cosh(u) / mpmath.sinh(u) ** 3

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        return sp.diff(self.rewrite(sp.Piecewise), self.args[0])


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
