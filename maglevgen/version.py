"""The package version: one place, imported by everything that prints or hashes it."""

__all__ = []

__version__ = "0.1.0"
