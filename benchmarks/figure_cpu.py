"""Figure CPU of ``softgen reproduce`` (issue 25), without a profiler.

    SOFTGEN_CACHE_DIR=... python benchmarks/figure_cpu.py EXP1,EXP2,... OUT

runs ``softgen reproduce EXP... --jobs 1 --out OUT`` and prints per experiment the
process CPU spent in the studies' figure functions (and in any Figure.savefig outside
them) against the experiment's CPU. cProfile inflates matplotlib's many small Python
calls far more than the simulations, so its shares overstate the figures.
"""
import functools
import importlib
import sys
import time

import matplotlib.figure
NAMES = ["gioste_runs", "theorem5_tracking", "fl_comparison", "adaptive_tracking", "robustness",
         "pendulum_tracking", "scenario_figure", "cascade_figure", "feedback_figure", "protocol_figure",
         "run_figure", "estimation_figure"]
MODS = ["figures_pneumatic", "soft", "electric", "estimation", "indices", "gioste_protocols", "gioste",
        "pneumatic", "pneumatic_fl", "pneumatic_robustness", "soft_claims", "gioste_claims", "excitation"]
acc = {"t": 0.0}
depth = [0]
def timed(f):
    @functools.wraps(f)
    def w(*a, **k):
        if depth[0]:
            return f(*a, **k)
        depth[0] += 1
        c = time.process_time()
        try:
            return f(*a, **k)
        finally:
            acc["t"] += time.process_time() - c
            depth[0] -= 1
    return w
wrapped = {}
for m in MODS:
    try:
        mod = importlib.import_module("softgen.studies." + m)
    except ImportError:
        continue
    for n in NAMES:
        if hasattr(mod, n):
            orig = getattr(mod, n)
            wrapped.setdefault(id(orig), timed(orig))
            setattr(mod, n, wrapped[id(orig)])
matplotlib.figure.Figure.savefig = timed(matplotlib.figure.Figure.savefig)
import softgen.app.reproduce as R  # noqa: E402  (after the figure functions are wrapped)
from softgen.cli import main  # noqa: E402
orig_run_one = R.run_one
per = {}
def run_one(*a, **k):
    t0, c = acc["t"], time.process_time()
    try:
        return orig_run_one(*a, **k)
    finally:
        per[str(a[0] if a else k)] = (acc["t"] - t0, time.process_time() - c)
R.run_one = run_one
exps, out = sys.argv[1].split(","), sys.argv[2]
sys.argv = ["softgen", "reproduce", *exps, "--jobs", "1", "--out", out]
try:
    main()
except SystemExit:
    pass
for k, (f, c) in per.items():
    print(f"FIG {k[:60]:60s} figures {f:6.2f} s of {c:6.2f} s CPU")
print(f"FIGTOTAL {sum(v[0] for v in per.values()):.2f} of {sum(v[1] for v in per.values()):.2f}")
