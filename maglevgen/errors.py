"""Errors the CLI turns into a one-line message and an exit code."""

from __future__ import annotations

__all__ = ["InputError", "MaglevError", "NoTrimError", "VerificationError"]


class MaglevError(Exception):
    """Base class: an error whose message is fit to show a user on one line."""

    exit_code = 1


class InputError(MaglevError):
    """Bad input: a malformed or inconsistent parameter file, a bad option, no trim (exit 2)."""

    exit_code = 2


class NoTrimError(InputError):
    """The carriage has no equilibrium at the requested speed."""


class VerificationError(MaglevError):
    """A verification failed (an embedded controller unstable in the envelope): exit 3. The
    outputs are written all the same so that the engineer can read why."""

    exit_code = 3

    def __init__(self, message: str, details: str | None = None) -> None:
        super().__init__(message)
        #: the whole reason (every failed check, its value, limit and command), which the
        #: one-line message points to: SUMMARY.md holds it, and --debug prints it
        self.details = details
