"""The package version: one place, imported by everything that prints or hashes it."""

__version__ = "0.1.0"
