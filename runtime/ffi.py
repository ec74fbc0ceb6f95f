"""Call generated functions from a compiled library through ctypes, in either precision.

casadi.external assumes casadi_real is double; this loader reads each function's CasADi API
(n_in, n_out, sparsity, work sizes) and passes arrays of the library's own real type.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

_INT = ctypes.c_longlong  # casadi_int as generated (long long int)


class GeneratedFunctionError(RuntimeError):
    """A generated function returned a non-zero MAGLEV_ERR_* code (maglev.h)."""

    def __init__(self, function: str, code: int) -> None:
        from maglevgen.codegen.checks import ERROR_CODES, error_name

        self.function, self.code, self.code_name = function, code, error_name(code)
        meaning = ERROR_CODES.get(self.code_name, (code, "unknown code"))[1]
        super().__init__(f"{function} returned {self.code_name} ({code}): {meaning}")


class GeneratedFunction:
    """One function of a generated library; call it with array-likes, get dense arrays."""

    def __init__(self, lib: ctypes.CDLL, name: str, real: type) -> None:
        self.name, self.real = name, np.dtype(real)
        creal = ctypes.c_float if self.real == np.float32 else ctypes.c_double
        self._fn = getattr(lib, name)
        self._fn.restype = ctypes.c_int
        n_in, n_out = getattr(lib, f"{name}_n_in"), getattr(lib, f"{name}_n_out")
        n_in.restype = n_out.restype = _INT
        sp_in, sp_out = getattr(lib, f"{name}_sparsity_in"), getattr(lib, f"{name}_sparsity_out")
        sp_in.restype = sp_out.restype = ctypes.POINTER(_INT)
        sp_in.argtypes = sp_out.argtypes = [_INT]
        self.shapes_in = [self._dense_shape(sp_in(i)) for i in range(n_in())]
        self.shapes_out = [self._dense_shape(sp_out(i)) for i in range(n_out())]
        work = getattr(lib, f"{name}_work")
        sz = [_INT() for _ in range(4)]
        work.restype = ctypes.c_int
        if work(*[ctypes.byref(s) for s in sz]):
            raise RuntimeError(f"{name}_work failed")
        self._sz_arg, self._sz_res, self._sz_iw, self._sz_w = (max(1, s.value) for s in sz)
        self._creal = creal

    def _dense_shape(self, sp: ctypes.POINTER) -> tuple[int, int]:
        rows, cols = sp[0], sp[1]
        if sp[2] == 1:  # CasADi's compact form of a dense pattern: (rows, cols, 1)
            return rows, cols
        if sp[2 + cols] != rows * cols:
            raise ValueError(f"{self.name}: sparse input/output is not supported here")
        return rows, cols

    def _flat(self, a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        arr = np.asarray(a, dtype=self.real)
        if arr.size != shape[0] * shape[1]:
            raise ValueError(f"{self.name}: input of size {arr.size}, expected {shape}")
        arr = arr.reshape(shape) if arr.ndim == 2 else arr.reshape(shape, order="F")
        return np.ascontiguousarray(arr.ravel(order="F"))

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        if len(args) != len(self.shapes_in):
            raise TypeError(f"{self.name} takes {len(self.shapes_in)} inputs, got {len(args)}")
        ins = [self._flat(a, s) for a, s in zip(args, self.shapes_in, strict=True)]
        outs = [np.zeros(r * c, dtype=self.real) for r, c in self.shapes_out]
        P = ctypes.POINTER(self._creal)
        arg = (P * self._sz_arg)(*[a.ctypes.data_as(P) for a in ins])
        res = (P * self._sz_res)(*[o.ctypes.data_as(P) for o in outs])
        iw = (_INT * self._sz_iw)()
        w = (self._creal * self._sz_w)()
        rc = self._fn(arg, res, iw, w, 0)
        if rc:
            raise GeneratedFunctionError(self.name, rc)
        return [o.reshape(s, order="F") for o, s in zip(outs, self.shapes_out, strict=True)]


class GeneratedLibrary:
    """A compiled generated library: ``lib.function("maglev_dynamics")(x, u, p)``."""

    def __init__(self, path: str | Path, precision: str = "double") -> None:
        self.path = Path(path)
        self._lib = ctypes.CDLL(str(self.path))
        self._real = np.float32 if precision == "single" else np.float64

    def function(self, name: str) -> GeneratedFunction:
        return GeneratedFunction(self._lib, name, self._real)
