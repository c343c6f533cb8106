#!/usr/bin/env python3
"""Compute the clamp force law (softgrip_ros.model.force_law) of the built-in gripper models and
write config/clamp_force/<model>.<law>.yaml: the L2 rod's for the paper's cavity types, the 3-D
FE's for the models fitted to it (type_II_fe, type_II_fe_l1; the FE extra, and minutes per
clamp sweep unless cached by scripts/bench_fe.py or an earlier run). --check only verifies that
every table is there and current (its inputs hash), exit 1 otherwise.

    python scripts/build_force_tables.py                 # every built-in model, both laws
    python scripts/build_force_tables.py --models type_II --laws l0
    python scripts/build_force_tables.py --check
"""
from __future__ import annotations

import argparse
import concurrent.futures
import datetime
import os
import pathlib
import platform
import sys
import time

# one BLAS thread per job: the rod's small matrices gain nothing from more, and two jobs each
# with a thread per core ran four times slower than one
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "src"))

from softgrip_ros.model import force_law, gripper_models  # noqa: E402

OUT = REPO / "config" / force_law.TABLE_DIR


def build(model: str, law: str) -> tuple[str, float]:
    started = time.monotonic()
    provenance = {"written_by": "scripts/build_force_tables.py",
                  "date": datetime.date.today().isoformat(),
                  "machine": f"CPython {platform.python_version()}, {platform.machine()}"}
    sweeps = None
    if force_law.table_source(model) is force_law.TableSource.FE3D:
        table, sweeps = force_law.compute_fe_table(
            model, law, progress=lambda *parts: print(f"  {model}.{law}:", *parts, flush=True))
        provenance["source"] = ("the 3-D FE with contact (softgrip_ros.model.fe3d.clamp), "
                                "w = 20 mm, rigid objects fixed in place, frictionless; below "
                                "the lowest pressure a sweep solved, its last force")
    else:
        table = force_law.compute_table(model, law)
        provenance["source"] = (f"the L2 rod, {force_law.ROD_ELEMENTS} elements per segment, "
                                "frictionless, rigid objects fixed in place")
    path = force_law.write_table(table, OUT / force_law.table_file_name(model, law), provenance,
                                 sweeps)
    return str(path.relative_to(REPO)), time.monotonic() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=list(gripper_models.built_in()))
    parser.add_argument("--laws", nargs="+", default=["l0", "l1"], choices=["l0", "l1"])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--check", action="store_true", help="verify, write nothing")
    args = parser.parse_args()
    unknown = sorted(set(args.models) - set(gripper_models.built_in()))
    if unknown:
        parser.error(f"not built-in models: {unknown}; built in: "
                     f"{list(gripper_models.built_in())}")
    pairs = [(m, law) for m in args.models for law in args.laws]
    if args.check:
        stale = []
        for model, law in pairs:
            try:
                force_law.load_table(model, law, compute_if_missing=False)
            except ValueError as error:
                stale.append(str(error))
        print("\n".join(stale) or f"{len(pairs)} tables current")
        return 1 if stale else 0
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(build, m, law): (m, law) for m, law in pairs}
        for done, future in enumerate(concurrent.futures.as_completed(futures), start=1):
            path, seconds = future.result()
            print(f"[{done}/{len(pairs)}] {path} ({seconds:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
