"""Validation cases with known answers, run with the default solver (``warpsph validate``).

- :mod:`.taylor_green`: the Taylor-Green vortex in a periodic box (analytic decay);
- :mod:`.lamb_oseen`: the Lamb-Oseen vortex (analytic viscous spreading);
- :mod:`.hydrostatic`: a tank at rest (density error, p = rho g h);
- :mod:`.dam_front`: the Martin & Moyce (1952) dam-break front (experiment);
- :mod:`.cases`: the runner behind ``warpsph validate CASE --resolutions N ...``, one row per method and
  resolution with the error, particles, steps and wall time.

The scripts tools/validate_*.py call these modules' ``main``.
"""

from .cases import CASES, validate

__all__ = ["CASES", "validate"]
