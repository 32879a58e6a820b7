#!/usr/bin/env bash
# Issue 34's goals, each measured the way the issue states it, with the load beside it.
#
#   benchmarks/goals.sh [GOAL ...]     GOAL: loops robustness mainjob tests generate peers
#                                      (default: all but peers)
#
# Every step runs from a fresh clone of this checkout's HEAD in $WORK (default a new
# temporary directory) with empty caches (SOFTGEN_CACHE_DIR, pip's), so that nothing
# compiled earlier is reused; CPU figures come from /usr/bin/time (user + sys of the
# process and its children) or from softgen's own CPU clocks. Take final figures on a
# quiet machine: `uptime` is printed before and after each step.
set -euo pipefail
HERE="$(cd "$(dirname "$0")/.." && pwd)"
WORK="${WORK:-$(mktemp -d /tmp/softgen-goals.XXXXXX)}"
GOALS=("${@:-loops robustness mainjob tests generate}")
GOALS=(${GOALS[*]})
PY="${PYTHON:-python3}"

say() { printf '\n== %s\n' "$*"; uptime; }

fresh_clone() {   # $1: directory; a clone of HEAD with its own venv, nothing built
  rm -rf "$1"
  git clone -q "$HERE" "$1"
  git -C "$1" checkout -q "$(git -C "$HERE" rev-parse HEAD)"
}

cpu_of() {        # user + sys seconds from a /usr/bin/time -v log
  awk -F': ' '/User time/ {u=$2} /System time/ {s=$2} END {printf "%.1f", u + s}' "$1"
}

wants() { [[ " ${GOALS[*]} " == *" $1 "* ]]; }

if wants mainjob; then
  say "main job (README command), fresh clone, empty caches"
  D="$WORK/mainjob"; fresh_clone "$D"; cd "$D"
  export PIP_NO_CACHE_DIR=1 SOFTGEN_CACHE_DIR="$WORK/cache-mainjob"
  rm -rf "$SOFTGEN_CACHE_DIR"
  /usr/bin/time -v bash -c "$PY -m venv .venv && .venv/bin/pip install -q --no-compile -e . && \
      .venv/bin/softgen generate --all && .venv/bin/softgen reproduce --out results" \
      > "$WORK/mainjob.log" 2> "$WORK/mainjob.time" || true
  grep -E "Elapsed|User time|System time" "$WORK/mainjob.time"
  echo "CPU-s (all processes): $(cpu_of "$WORK/mainjob.time")   goal: wall < 3 min at low load"
  unset PIP_NO_CACHE_DIR SOFTGEN_CACHE_DIR
  cd "$HERE"; uptime
fi

if wants generate; then
  say "generate --all on a fresh clone: compile CPU (bundles up to date: compiles only)"
  D="$WORK/generate"; fresh_clone "$D"; cd "$D"
  $PY -m venv .venv && .venv/bin/pip install -q --no-compile -e .
  /usr/bin/time -v .venv/bin/softgen generate --all > "$WORK/generate.log" 2> "$WORK/generate.time"
  echo "generate --all CPU-s (compiles + Python): $(cpu_of "$WORK/generate.time")   goal: <= 60 CPU-s of compiles"
  cd "$HERE"; uptime
fi

if wants tests; then
  say "default test suite, fresh clone, empty cache (the README's test command)"
  D="$WORK/tests"; fresh_clone "$D"; cd "$D"
  export SOFTGEN_CACHE_DIR="$WORK/cache-tests" SOFTGEN_TEST_CPU="$WORK/tests-cpu.txt"
  rm -rf "$SOFTGEN_CACHE_DIR" "$SOFTGEN_TEST_CPU"
  $PY -m venv .venv && .venv/bin/pip install -q --no-compile -e '.[test,dask]'
  /usr/bin/time -v .venv/bin/python -m pytest -q > "$WORK/tests.log" 2> "$WORK/tests.time" || true
  tail -1 "$WORK/tests.log"
  echo "test suite CPU-s: $(cpu_of "$WORK/tests.time")   goal: <= 150"
  echo "costliest tests (CPU-s total, self, children, wall):"
  sort -rn "$SOFTGEN_TEST_CPU" | head -15
  unset SOFTGEN_CACHE_DIR SOFTGEN_TEST_CPU
  cd "$HERE"; uptime
fi

if wants loops || wants robustness || wants peers; then
  D="$WORK/bench"; fresh_clone "$D"; cd "$D"
  $PY -m venv .venv && .venv/bin/pip install -q --no-compile -e ".[test,dask]"
  export SOFTGEN_CACHE_DIR="$WORK/cache-bench"
  .venv/bin/softgen generate --all > /dev/null
fi

if wants loops; then
  say "loop goals: one fresh process, CPU clock (bench --json)"
  .venv/bin/softgen bench planar_2link_mckibben pcc_3d_4seg arm_2link_electric \
      --calls 20000 --json "$WORK/bench.json" > "$WORK/bench.log" || true
  .venv/bin/python - "$WORK/bench.json" <<'EOF'
import json, sys
r = {m["model"]: m for m in json.load(open(sys.argv[1]))["models"]}
t5 = r["planar_2link_mckibben"]["loops"]["theorem5"]
t10 = r["pcc_3d_4seg"]["loops"]["theorem10"]
cas = r["arm_2link_electric"]
print(f"Theorem 5, 7 signals: {t5['sim_s_per_cpu_s']:.0f}x real time (CPU)   goal >= 3000x")
print(f"3D PCC Theorem 10:    {t10['sim_s_per_cpu_s']:.0f}x real time (CPU)   goal >= 200x")
print(f"cascade step:         {cas['cascade_step_ns']:.0f} ns (CPU, C loop)    goal < 300 ns")
print(f"  (the whole cascade loop with the motor plant: "
      f"{cas['loops']['cascade_loop']['cpu_ns_per_sample']:.0f} ns per sample)")
EOF
  uptime
fi

if wants robustness; then
  say "ext-robustness-theorem5 at its default size (the study of record)"
  /usr/bin/time -v .venv/bin/softgen reproduce ext-robustness-theorem5 --out "$WORK/rob" \
      > "$WORK/rob.log" 2> "$WORK/rob.time" || true
  .venv/bin/python - "$WORK/rob/ext-robustness-theorem5/metrics.json" <<'EOF'
import json, sys
m = json.load(open(sys.argv[1]))
m = m.get("metrics", m)
print(f"samples: {sum(v for k, v in m.items() if k.startswith('samples_') and k != 'samples_per_wall_second'):.0f}, "
      f"all: {m['samples_all']:.0f}, per group: {m['samples_inertial']:.0f}")
print(f"samples_per_wall_second: {m['samples_per_wall_second']:.1f}   goal >= 40 on 2 CPUs")
EOF
  echo "CPU-s of the reproduce: $(cpu_of "$WORK/rob.time")"
  uptime
fi

if wants peers; then
  say "bench --peers (needs pip install '.[peers]'): like-for-like ratios, flags named"
  .venv/bin/pip install -q -e ".[peers]"
  .venv/bin/softgen bench --peers | tee "$WORK/peers.log"
  uptime
fi
echo "logs in $WORK"
