"""maglevgen: Inductrack maglev carriage dynamics and control, derived symbolically, as C."""

__version__ = "0.1.0"


def _install_derivation_store() -> None:
    """Share the derivation's memoised steps across processes (derive/ itself does no I/O)."""
    from .cache import STORE
    from .derive.memo import set_store

    set_store(STORE)


_install_derivation_store()
