"""Wall time of ``ext-robustness-theorem5`` with 1 and 2 workers (issue 17), and whether
the metrics agree. Not a test: a measurement.

    .venv/bin/python benchmarks/robustness_workers.py [--workers 1 2] [--out /tmp/rob]
"""
from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from softgen.experiments.ext_robustness import RobustnessConfig, run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", default="/tmp/softgen-robustness-workers")
    args = ap.parse_args()
    flats = {}
    for w in args.workers:
        out = Path(args.out) / f"workers{w}"
        shutil.rmtree(out, ignore_errors=True)     # no resumed samples: time every run
        out.mkdir(parents=True)
        t0 = time.perf_counter()
        flat = run(RobustnessConfig(workers=w), out).flat()
        wall = time.perf_counter() - t0
        n = sum(v for k, v in flat.items() if k.startswith("samples_")
                and k != "samples_per_wall_second")
        print(f"workers {w}: {n:.0f} samples in {wall:.1f} s ({n / wall:.2f} samples/s)")
        flats[w] = {k: v for k, v in flat.items() if "wall" not in k}
    first = next(iter(flats.values()))
    differ = sorted({k for f in flats.values() for k in f if f[k] != first.get(k)})
    print("metrics identical across worker counts" if not differ else f"differ: {differ}")


if __name__ == "__main__":
    main()
