"""Generalisation benchmark: random structures identified blind (issue 20, linear part).

Nothing here but :mod:`.runner` imports ``fnsi``: the cases and their truth are built
with numpy and scipy alone, so the benchmark does not inherit the library's assumptions.

- :mod:`.structures`: random chains, trees and grids (masses, springs, proportional or
  non-proportional damping, optional nonlinear elements) and their exact modes;
- :mod:`.synthesis`: exact periodic steady state of a linear structure in the frequency
  domain, and each mode's share of the response power;
- :mod:`.integration`: periodic steady state with nonlinear elements by adaptive time
  integration (for the hidden-effect cases of issue 21; checked against :mod:`.synthesis`
  on linear structures);
- :mod:`.cases`: phase 1, the random draw of every case, written with its truth sealed;
- :mod:`.blind`: the directory layout and the rules that keep the phases blind;
- :mod:`.runner`: phase 2, the library on the data only;
- :mod:`.scoring`: phase 3, the answers against the truth, and the results table.

Entry point: ``benchmarks/generalisation.py``.
"""
