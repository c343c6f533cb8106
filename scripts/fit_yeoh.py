#!/usr/bin/env python3
"""Fit Yeoh constants to a uniaxial tensile test, by the paper's linearised least squares.

DATA.csv has a header and two columns: ``stretch`` (lambda) or ``strain`` (lambda - 1),
then the nominal stress as ``stress_pa``, ``stress_kpa`` or ``stress_mpa``.

    python scripts/fit_yeoh.py DATA.csv [--c30] [--plot fit.png] [--json]
"""
import argparse
import json
import sys

import numpy as np

from softgrip_ros.model.material import fit_yeoh, load_tensile_csv


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", help="CSV of stretch|strain and nominal stress")
    parser.add_argument("--c30", action="store_true", help="fit C30 as well (default: C30 = 0)")
    parser.add_argument("--confidence", type=float, default=0.95,
                        help="confidence level of the intervals")
    parser.add_argument("--plot", metavar="PNG", help="draw the data against the fit")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    if not 0.5 <= args.confidence < 1.0:
        parser.error("--confidence must lie in [0.5, 1)")
    try:
        stretch, stress = load_tensile_csv(args.data)
        fit = fit_yeoh(stretch, stress, include_c30=args.c30, confidence_level=args.confidence)
    except (OSError, ValueError) as error:
        print(f"fit_yeoh: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(
            json.dumps(
                {
                    "c10_pa": fit.material.c10_pa, "c20_pa": fit.material.c20_pa,
                    "c30_pa": fit.material.c30_pa, "standard_errors_pa": fit.standard_errors_pa,
                    "confidence_intervals_pa": fit.confidence_intervals_pa,
                    "confidence_level": fit.confidence_level, "points": fit.points
                }, indent=2))
    else:
        print(fit.summary())
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        dense = np.linspace(min(stretch.min(), 1.0), stretch.max(), 300)
        figure, axis = plt.subplots(figsize=(6, 4))
        axis.plot(stretch, stress / 1e3, "o", ms=4, label="data")
        axis.plot(
            dense,
            fit.material.uniaxial_nominal_stress(dense) / 1e3, "-", label=
            f"Yeoh fit: C10 = {fit.material.c10_pa / 1e6:.4f}, C20 = "
            f"{fit.material.c20_pa / 1e6:.4f}"
            + (f", C30 = {fit.material.c30_pa / 1e6:.5f}" if args.c30 else "") + " MPa")
        axis.set_xlabel("stretch lambda")
        axis.set_ylabel("nominal stress (kPa)")
        axis.set_title("Uniaxial tensile test and Yeoh fit")
        axis.grid(alpha=0.3)
        axis.legend()
        figure.tight_layout()
        figure.savefig(args.plot, dpi=120)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
