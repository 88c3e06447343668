#!/usr/bin/env python3
"""Check that an mvao LAS/LAZ output shows its `ao` dimension to other readers.

Usage: check_las_ao.py FILE [--expect-count N] [--expect-first V]

Reads FILE with laspy (pip install laspy; 'laspy[lazrs]' for LAZ) and, when the `pdal`
command is installed, with PDAL too. Prints the point format, the extra dimensions and
statistics of `ao`; exits non-zero when `ao` is missing, outside [0, 1], not finite, or
differs from the expectations given. `--expect-first` is the value of point 1 (the second).
"""

import argparse
import json
import math
import shutil
import subprocess
import sys


def check_laspy(path, expect_count, expect_first):
    import laspy

    las = laspy.read(path)
    names = list(las.point_format.extra_dimension_names)
    print(
        f"laspy {laspy.__version__}: LAS {las.header.version}, point format "
        f"{las.header.point_format.id}, {len(las.points)} points, extra dims {names}"
    )
    if "ao" not in names:
        sys.exit(f"{path}: laspy sees no 'ao' dimension")
    ao = las["ao"]
    if str(ao.dtype) != "float32":
        sys.exit(f"{path}: 'ao' is {ao.dtype}, expected float32")
    lo, hi = float(ao.min()), float(ao.max())
    mean = float(ao.mean())
    print(f"  ao: min {lo:.4f} max {hi:.4f} mean {mean:.4f}")
    if not all(math.isfinite(v) for v in (lo, hi, mean)) or lo < 0.0 or hi > 1.0:
        sys.exit(f"{path}: 'ao' outside [0, 1] or not finite")
    if expect_count is not None and len(ao) != expect_count:
        sys.exit(f"{path}: {len(ao)} ao values, expected {expect_count}")
    if expect_first is not None and abs(float(ao[1]) - expect_first) > 1e-6:
        sys.exit(f"{path}: ao[1] = {float(ao[1])}, expected {expect_first}")
    if las.header.point_format.id in (2, 3, 5, 7, 8, 10):
        print(f"  rgb of point 0: {las.red[0]}, {las.green[0]}, {las.blue[0]}")


def check_pdal(path):
    pdal = shutil.which("pdal")
    if pdal is None:
        print("  pdal: not installed, skipped")
        return
    out = subprocess.run(
        [pdal, "info", "--stats", "--dimensions", "ao", path],
        capture_output=True,
        text=True,
    )
    if out.returncode != 0:
        sys.exit(f"{path}: pdal info failed: {out.stderr.strip()}")
    stats = json.loads(out.stdout)["stats"]["statistic"]
    ao = next((s for s in stats if s["name"] == "ao"), None)
    if ao is None:
        sys.exit(f"{path}: pdal sees no 'ao' dimension")
    print(f"  pdal: ao min {ao['minimum']:.4f} max {ao['maximum']:.4f} count {ao['count']}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file")
    ap.add_argument("--expect-count", type=int)
    ap.add_argument("--expect-first", type=float)
    args = ap.parse_args()
    try:
        import laspy  # noqa: F401
    except ImportError:
        print("laspy: not installed, skipped (pip install laspy)")
    else:
        check_laspy(args.file, args.expect_count, args.expect_first)
    check_pdal(args.file)
    print("ok")


if __name__ == "__main__":
    main()
