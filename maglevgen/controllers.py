"""The registry of controllers: what every layer asks about a controller, by its name.

`Controller` is the record (its gains at an operating point, its title and description,
whether the firmware may embed it, the C tick that runs it, how the FMU carries its gains, its
design weights, its line style); `register` adds one; `names`, `embeddable`, `controller`,
`title` and `titles` read the registry when asked, never a copy made at import, so a
controller registered after `maglevgen.load()` is a choice of every command.

The definitions live in maglevgen/control/: ``registry.py`` the record and the table,
``paper_designs.py`` and ``spec.py`` the built-in controllers, which the package
`maglevgen.control` registers as it loads (in that order). This module is the registry's one
public name; it is not ``control``, python-control's name, which the API also imports.
"""

from __future__ import annotations

from maglevgen.control.registry import (
    REGISTRY,
    Controller,
    controller,
    embeddable,
    names,
    register,
    title,
)

__all__ = ["REGISTRY", "Controller", "controller", "embeddable", "names", "register", "title"]
