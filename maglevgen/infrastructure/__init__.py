"""Infrastructure every stage shares, with no physics in it: the on-disk cache and its keys
(``cache``, ``hashing``: the one content-hash helper), atomic output folders (``output``),
progress lines on stderr (``progress``), a second process for the figures (``workers``), a
table column's numbers in one notation (``columns``: the report, SUMMARY.md and metrics.md) and
TeX for report.pdf (``texsetup``, `make run`'s first step).

Nothing here imports the derivation, the generated C or the analyses; everything else may
import from here.
"""
