"""Validation cases with known answers, run with the default solver (``warpsph validate``), and the studies.

Each case is a package of its own, with its README and, where the reference is measured or tabulated, its
``reference.json`` (README.md here lists them):

- :mod:`.taylor_green`: the Taylor-Green vortex in a periodic box (analytic decay);
- :mod:`.lamb_oseen`: the Lamb-Oseen vortex (analytic viscous spreading), in a box and below a free surface;
- :mod:`.standing_wave`: the first sloshing mode of a tank (linear theory);
- :mod:`.hydrostatic`: a tank at rest (density error, p = rho g h);
- :mod:`.dam_front`: the Martin & Moyce (1952) dam-break front (experiment);
- :mod:`.rest`: tanks at rest under gravity (the largest speed);
- :mod:`.sinking`: a sphere sinking in a viscous fluid (Stokes-Oseen drag, Haberman & Sayre's wall factor);
- :mod:`.cases`: the runner behind ``warpsph validate CASE --resolutions N ...``, one row per method and
  resolution with the error, particles, steps and wall time.

The studies, each with ``add_arguments``, ``command`` and ``main`` (``warpsph COMMAND``):

- :mod:`.pareto`: cost against accuracy and the Pareto front (``warpsph pareto``);
- :mod:`.stress`: the numerical-stability matrix (``warpsph stress``);
- :mod:`.bench`: ms per step and per stage of a scene at ~N particles (``warpsph bench steps``);
- :mod:`.bench_job`: the whole job with its output, and the time to the first step (``warpsph bench job``);
- :mod:`.results`: the figures of result JSON files (``warpsph plot results``).

Some cases run alone too, e.g. ``python -m warpsph.validation.dam_front --help``.
"""

from .cases import CASES, validate
from warpsph.errors import SceneError
from warpsph.log import configure

__all__ = ["CASES", "validate", "study_main"]


def study_main(doc, add_arguments, command, argv=None):
    """A study's script entry point: its options (``add_arguments``), then ``command(args)`` with the
    ``warpsph`` logger shown on stderr; a :class:`~warpsph.errors.SceneError` naming an option becomes
    argparse's usage error."""
    import argparse

    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    args = parser.parse_args(argv)
    undo = configure()  # progress and warnings on stderr, as under ``warpsph COMMAND``
    try:
        return command(args)
    except SceneError as exc:
        parser.error(str(exc))
    finally:
        undo()
