"""Symbolic derivation of the Inductrack carriage model (SymPy, no I/O).

``conventions`` (state and input order) and ``structure`` (what the derivation and the caches
depend on besides parameter values) import no SymPy, so running the compiled model needs none.
The other modules mirror the paper: ``rigid_body`` (eqs 1-2), ``inductrack`` (eqs 3-4), ``geometry``
(eqs 8-12), ``model`` (assembly), ``linearize`` (eqs 5-19), ``trim``; beyond it ``distributed``
(eq 3 summed over a tilted face) and ``circuit_lag`` (the circuits' first-order lag of a moving
gap, model.circuit_dynamics); the controller modules
(``riccati``, ``damping``, ``allocation``) implement eqs 20-33 and ``paper`` keeps the paper's
printed forms for comparison only.
"""
