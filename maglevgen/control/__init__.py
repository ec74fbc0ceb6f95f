"""The controllers: one registry, one definition per controller, and what runs them.

The folder: ``registry`` (the `Controller` record and `register`), one module per family of
controllers (``paper_designs``: the paper's; ``spec``: the design to ``[control.spec]``),
``lqr`` (the Riccati solves they share), ``operating`` (trim, gains and the linearised closed
loop at one speed, from the C), ``schedule`` (gain schedules over speed), ``sampled`` (the loop
as the firmware runs it: tick, hold, delay, speed loop), ``plant`` (the loop as built with the
actuator lag at one operating point, from one state layout, and the `spec` design at the tick
on it), ``built_loop`` (that loop's settings in one type, `LoopSetting`: tick, delay, lag,
speed loop, budget, and what the C loop, the host run and the FMU read from it),
``carriage_plant`` (the `Plant`: one carriage and model choice with its library, speed range,
cached operating points, loop as built, gain table and launch schedule, what the analyses,
exports and report take), ``margins``
(disk and delay margins at the actuators) and ``symbolic_reference`` (the same designs on the
lambdified SymPy model: the tests' reference).

A controller is data (`Controller`): its name and title, whether the firmware may embed it,
whether it is one of the paper's designs, how its gains are computed at an operating point,
the generated C tick that runs it, how the FMU carries its gains and how figures draw it.
Every consumer (the CLI's choices, the API's validation, the operating point, the schedule,
the envelope, the FMU, the report and the figures) reads the registry through
`maglevgen.controllers` (its public name, apart from python-control's ``control``) when it
needs it (no copy at import: a controller registered after `maglevgen.load()` is one), and
branches on the controller's fields, never on its name; adding a linear controller is one
module that calls `register` (see `spec`) and its test. Loading this package registers the
built-in controllers.

Every controller here acts on the axis coordinates a = (y, z, phi, theta, psi) and their
rates a' with 5 x 5 gain matrices, u_gen = -(K_pos (a - a_ref) + K_rate a').
"""

from __future__ import annotations

from maglevgen.control import paper_designs, spec  # noqa: F401  (each registers its controllers, in this order)

__all__: list[str] = []  # the registry's public name is `maglevgen.controllers`
