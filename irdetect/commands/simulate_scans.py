"""Write simulated radar-style measurement scans (/scans, /truth) to an HDF5 file.

Scenarios (data/presets, kind = "scans"): zhang2010 (3 CV targets in Poisson clutter over
120 km x 120 km, Cartesian noise 100 m) and liang2015 (2-D radar at the origin, 5 targets,
range / azimuth noise, clutter mean 50 per scan). docs/initiation.md states every assumption.
"""

from __future__ import annotations

import logging

from irdetect.io.scans import write_scans
from irdetect.simulate.scans import simulate_scans

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("output", help="HDF5 file to write")
    p.add_argument("--scenario", default="zhang2010",
                   help="zhang2010, liang2015 or a scans TOML preset (default: zhang2010)")
    p.add_argument("--clutter-density", type=float,
                   help="Cartesian scenarios: clutter points per km^2 per scan")
    p.add_argument("--clutter-mean", type=float,
                   help="mean clutter count per scan (overrides the density)")
    p.add_argument("--scans", type=int, dest="n_scans", help="number of scans")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: fresh entropy)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


#: scenario key -> the option that sets it
OPTIONS = {"clutter_density": "--clutter-density", "clutter_mean": "--clutter-mean",
           "n_scans": "--scans"}


def run(args) -> int:
    from irdetect.commands.simulate import check_seed, given_options
    from irdetect.errors import InputError, name_options
    from irdetect.io import check_output_path

    check_output_path(args.output, args.force)
    try:
        scans, truth, attrs = simulate_scans(
            args.scenario, rng=check_seed(args.seed), clutter_density=args.clutter_density,
            clutter_mean=args.clutter_mean, n_scans=args.n_scans)
    except InputError as exc:
        raise name_options(exc, given_options(args, OPTIONS)) from None
    attrs["seed"] = -1 if args.seed is None else args.seed
    write_scans(args.output, scans, truth=truth, attrs=attrs, force=args.force)
    log.info("wrote %s: %d scans, %d measurements, %d targets", args.output,
             attrs["n_scans"], len(scans), len(set(truth["target"])))
    return 0
