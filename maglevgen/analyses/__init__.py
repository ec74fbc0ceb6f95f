"""The analyses of a carriage, all run on the compiled C (maglevgen.runtime.library):

- ``queries``: the numbers `maglevgen trim`, `gains` and `envelope` print, as plain data (the
  report and SUMMARY.md read the same);
- ``envelope``: stability and the specification verdicts across [v_min, v_max];
- ``simulate`` and ``sim_output``: the closed-loop hold and launch runs (figs 3-8) and what
  they write; ``run_spec``: a run judged against ``[control.spec]``;
- ``montecarlo``: robustness over the tolerances; ``roa``: a sampled region of attraction;
- ``magnetic_damping``: the track circuits' damping per axis (the circuit lag).

They sit above the controllers (maglevgen.control) and below the exports (firmware, FMU), the
report and the build.
"""
