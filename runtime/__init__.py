"""Compile, load and integrate the generated C (the thin runtime)."""
