"""maglevgen: Inductrack maglev carriage dynamics and control, derived symbolically, as C."""

__version__ = "0.1.0"
