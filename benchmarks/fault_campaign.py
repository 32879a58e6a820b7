"""A fault campaign against every ``softgen`` verb: generated hostile attempts, each run in
a fresh process and sandbox, classified clean or unclean.

Usage::

    .venv/bin/python benchmarks/fault_campaign.py [--jobs 2] [--seed 36] [--verbs a,b]
        [--limit N] [--plugin MODULE ...] [--json FILE] [--list] [--keep DIR]

What is tried, per verb (``GENERATORS``; ``--list`` prints every attempt): bad files
(random bytes, UTF-16, NUL, truncated, deeply nested, huge numbers), bad keys and shapes
(mutations of valid model, system and log files), hostile actuator laws, odd paths
(missing, a directory for a file and a file for a directory, relative, names with
spaces, quotes and newlines, an output that is an input), a nearly full disk (a tiny
tmpfs when this process may mount one, else the in-process byte budget of
``tests/fault_disk.py``), signals at random moments, and huge sizes (links, segments,
states, delays, harmonics, periods, log rows).

An attempt is **unclean** when any of these holds (else clean):

``traceback``  a Python traceback on stderr;
``wrong``      status 0 with an output that fails its own loader (a model file the
               loader refuses, a bundle whose C does not match its manifest, an export
               whose record does not match its files, ...) or with a result the attempt
               knows to be implausible;
``lost``       a file that existed before changed or vanished, and the command did not
               ask to overwrite it (``--force`` for that output);
``orphan``     a process of the attempt's session alive a second after it ended;
``silent``     more than 10 s without a line on stdout or stderr (stderr is a
               terminal, as for a user, so progress lines show);
``hang``       still running at the attempt's timeout (killed);
``crash``      ended by a signal the campaign did not send, or a non-zero status
               without a ``softgen: error:`` line.

The attempts are in ``benchmarks/fault_attempts.py`` and (the verbs and model classes of
issues 33 and 35: Cosserat rods, statics, floating bases, bench, export --set)
``benchmarks/fault_attempts_round3.py``. Adding a verb: write a generator
``def attempts(rng, ctx) -> Iterable[Attempt]`` decorated with ``@generator("verb")``
there, or in a module given with ``--plugin`` (imported before the campaign; it may use
everything both modules define). A verb the CLI has and no generator covers still gets
the generic attempts of ``fault_attempts.generic`` (no arguments, junk options, missing
and odd paths).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import importlib
import json
import os
import pty
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
SILENT = 10.0
PY = sys.executable


# -- attempts -----------------------------------------------------------------------------

@dataclasses.dataclass
class Attempt:
    """One run of the CLI. Paths in ``argv``, ``outputs`` and ``may_change`` are relative
    to the attempt's sandbox (its working directory); ``{d}`` is replaced by the
    sandbox's absolute path where an absolute path is wanted."""

    verb: str
    name: str
    argv: list[str]
    setup: Callable[[Path], None] | None = None
    #: (path, kind) validated by LOADERS when the status is 0.
    outputs: tuple[tuple[str, str], ...] = ()
    #: Pre-existing paths (files or directories) the command may change.
    may_change: tuple[str, ...] = ()
    #: Pre-existing paths it may change only when it succeeds (an output given --force,
    #: of an attempt whose signal may come after the run ended).
    may_change_on_success: tuple[str, ...] = ()
    #: Bytes left on the sandbox's ``disk/`` directory (None: no limit).
    disk: int | None = None
    #: (signal, seconds after start) sent to the command's process.
    signal: tuple[int, float] | None = None
    timeout: float = 150.0
    env: dict = dataclasses.field(default_factory=dict)
    #: Extra judgement of a finished run: a reason it is wrong, or None.
    judge: Callable[[Run], str | None] | None = None
    #: Fake experiments registered in the child: id -> "module:ATTR" (module in sandbox).
    fakes: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class Run:
    attempt: Attempt
    status: int | None
    stdout: str
    stderr: str
    seconds: float
    silent: float
    orphans: list[int]
    changed: list[str]
    verdict: str = "clean"
    detail: str = ""


GENERATORS: dict[str, list[Callable]] = defaultdict(list)


def generator(verb: str):
    """Register ``f(rng, ctx) -> Iterable[Attempt]`` for ``verb``."""
    def deco(f):
        GENERATORS[verb].append(f)
        return f
    return deco


# -- running and judging ----------------------------------------------------------------------

WRAPPER = r"""
import json, os, sys
cfg = json.loads(sys.argv[1])
if cfg.get("disk_budget") is not None:
    sys.path.insert(0, cfg["tests"])
    import fault_disk
    fault_disk.install(cfg["disk_root"], cfg["disk_budget"])
if cfg.get("fakes"):
    sys.path.insert(0, cfg["syspath"])
    from softgen.experiments import registry
    registry._MODULES.update(cfg["fakes"])
sys.argv[0] = "softgen"
from softgen.cli import main
sys.exit(main(cfg["argv"]))
"""


def _snapshot(d: Path) -> dict[str, str]:
    out = {}
    for p in sorted(d.rglob("*")):
        rel = str(p.relative_to(d))
        if rel.startswith("cache") or "/cache/" in rel:
            continue
        try:
            if p.is_symlink():
                out[rel] = "link:" + os.readlink(p)
            elif p.is_fifo():
                out[rel] = "fifo"
            elif p.is_file():
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        except OSError:
            pass
    return out


def _session(sid: int) -> list[int]:
    alive = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            alive.append(int(proc.name))
    return alive


class Disk:
    """``sandbox/disk`` with a byte budget: a tmpfs when mounting works, else None (the
    child then installs tests/fault_disk.py's in-process budget)."""

    usable: bool | None = None

    @classmethod
    def check(cls, where: Path) -> bool:
        if cls.usable is None:
            probe = where / "probe"
            probe.mkdir(parents=True, exist_ok=True)
            cls.usable = os.geteuid() == 0 and subprocess.run(
                ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(probe)],
                capture_output=True).returncode == 0
            if cls.usable:
                subprocess.run(["umount", str(probe)], capture_output=True)
        return cls.usable


def _mount(disk: Path, setup, sandbox: Path, budget: int) -> bool:
    disk.mkdir(parents=True, exist_ok=True)
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256m", "tmpfs", str(disk)],
                      capture_output=True).returncode != 0:
        return False
    if setup is not None:
        setup(sandbox)
    used = sum(p.stat().st_blocks * 512 for p in disk.rglob("*") if p.is_file())
    size = max(4096, used + budget)
    subprocess.run(["mount", "-o", f"remount,size={size}", str(disk)], capture_output=True)
    return True


def run_attempt(a: Attempt, ctx, root: Path, index: int, cache: Path) -> Run:
    sandbox = root / f"a{index:04d}"
    sandbox.mkdir(parents=True)
    disk = sandbox / "disk"
    mounted = False
    cfg = {"argv": [x.replace("{d}", str(sandbox)) for x in a.argv], "tests": str(TESTS)}
    try:
        if a.disk is not None and Disk.check(root):
            mounted = _mount(disk, a.setup, sandbox, a.disk)
        if not mounted:
            disk.mkdir(exist_ok=True)
            if a.setup is not None:
                a.setup(sandbox)
            if a.disk is not None:
                cfg.update(disk_budget=a.disk, disk_root=str(disk))
        if a.fakes:
            cfg.update(fakes=a.fakes, syspath=str(sandbox))
        before = _snapshot(sandbox)
        env = {**os.environ, "SOFTGEN_CACHE_DIR": str(cache),
               **{k: v.replace("{d}", str(sandbox)) for k, v in a.env.items()}}
        run = _execute(a, cfg, sandbox, env)
        after = _snapshot(sandbox)
        allowed = [m.replace("{d}", str(sandbox)) for m in a.may_change
                   + (a.may_change_on_success if run.status == 0 else ())]
        run.changed = [k for k, v in before.items() if after.get(k) != v and
                       not any(k == m or k.startswith(m.rstrip("/") + "/") for m in allowed)]
        _judge(run, sandbox)
        return run
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def _execute(a: Attempt, cfg: dict, sandbox: Path, env: dict) -> Run:
    master, slave = pty.openpty()
    t0 = time.monotonic()
    proc = subprocess.Popen([PY, "-c", WRAPPER, json.dumps(cfg)], cwd=sandbox, env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave,
                            start_new_session=True)
    os.close(slave)
    last = [time.monotonic()]
    out_chunks: list[bytes] = []
    err_chunks: list[bytes] = []

    def pump(read, sink):
        while True:
            try:
                data = read()
            except OSError:
                break
            if not data:
                break
            sink.append(data)
            last[0] = time.monotonic()
    threads = [threading.Thread(target=pump, args=(lambda: proc.stdout.read1(65536),
                                                   out_chunks), daemon=True),
               threading.Thread(target=pump, args=(lambda: os.read(master, 65536), err_chunks),
                                daemon=True)]
    for t in threads:
        t.start()
    silent, sent, hung = 0.0, False, False
    while proc.poll() is None:
        now = time.monotonic()
        silent = max(silent, now - last[0])
        if a.signal is not None and not sent and now - t0 >= a.signal[1]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, a.signal[0])
            sent = True
        if now - t0 > a.timeout:
            hung = True
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.05)
    proc.wait()
    seconds = time.monotonic() - t0
    time.sleep(1.0)
    orphans = _session(proc.pid)
    for pid in orphans:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    for t in threads:
        t.join(timeout=2)
    with contextlib.suppress(OSError):
        os.close(master)
    run = Run(a, None if hung else proc.returncode,
              b"".join(out_chunks).decode(errors="replace"),
              b"".join(err_chunks).decode(errors="replace").replace("\r\n", "\n"),
              seconds, silent, orphans, [])
    run.detail = "hang" if hung else ""
    return run


def _judge(run: Run, sandbox: Path) -> None:
    a = run.attempt
    errors = [ln for ln in run.stderr.splitlines() if ln.startswith("softgen: error:")]
    first = errors[0][:200] if errors else ""
    sent = a.signal[0] if a.signal else None
    if run.status is None:
        run.verdict, run.detail = "hang", f"still running after {a.timeout:.0f} s"
    elif "Traceback (most recent call last)" in run.stderr:
        tail = [ln for ln in run.stderr.splitlines() if ln.strip()][-1:]
        run.verdict, run.detail = "traceback", (tail[0][:200] if tail else "")
    elif run.changed:
        run.verdict, run.detail = "lost", "changed: " + ", ".join(run.changed[:4])
    elif run.orphans:
        run.verdict, run.detail = "orphan", f"{len(run.orphans)} process(es) left"
    elif run.silent > SILENT:
        run.verdict, run.detail = "silent", f"{run.silent:.0f} s without output"
    elif run.status < 0 and -run.status != sent:
        run.verdict, run.detail = "crash", f"killed by {signal.Signals(-run.status).name}"
    elif run.status > 0 and not errors and run.status not in (1,) and "usage:" not in \
            run.stderr:
        run.verdict, run.detail = "crash", f"status {run.status} without an error line"
    elif run.status == 0:
        for path, kind in a.outputs:
            why = check_output(sandbox / path.replace("{d}", str(sandbox)), kind)
            if why:
                run.verdict, run.detail = "wrong", f"{path}: {why}"
                break
        else:
            why = a.judge(run) if a.judge else None
            if why:
                run.verdict, run.detail = "wrong", why
    if run.verdict == "clean":
        run.detail = first or (f"status {run.status}")


# -- output loaders ---------------------------------------------------------------------------

def check_output(path: Path, kind: str) -> str | None:
    """Why the output at ``path`` fails its own loader (None: it loads, or is absent)."""
    if not path.exists():
        return None if kind in ("results", "sweep") else "missing after status 0"
    try:
        return LOADERS[kind](path)
    except Exception as exc:            # noqa: BLE001 - any failure is the verdict
        return f"{type(exc).__name__}: {str(exc).splitlines()[0][:150] if str(exc) else ''}"


def _model(p: Path):
    from softgen.modelfile.load import load_model
    load_model(p)


def _bundle(p: Path):
    from softgen.codegen.build import check_source, read_manifest
    check_source(p, read_manifest(p))


def seal(record: dict) -> str:
    """A record's seal, computed here (as softgen.core.provenance.seal and the export
    record define it) so that the campaign also judges versions without that function."""
    body = {k: v for k, v in record.items() if k != "seal"}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def _export(p: Path):
    rec = json.loads((p / "softgen_export.json").read_text())
    assert rec["seal"] == seal(rec), "record seal"
    for name, digest in rec["files"].items():
        assert hashlib.sha256((p / name).read_bytes()).hexdigest() == digest, name


def _csv(p: Path):
    import csv
    rows = list(csv.reader(p.open()))
    assert len(rows) >= 2, "no data rows"
    for r in rows[1:]:
        [float(x) for x in r if x != ""]


def _png(p: Path):
    assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"


def _json(p: Path):
    json.loads(p.read_text())


def _observer(p: Path):
    from softgen.codegen.build import read_manifest
    read_manifest(p)


def _results(p: Path):
    for m in p.glob("*/metrics.json"):
        data = json.loads(m.read_text())
        # (a version that writes no seal is judged by the attempt's own judge instead)
        assert "seal" not in data or data["seal"] == seal(data), \
            f"{m.parent.name}: metrics.json seal"


def _sweep(p: Path):
    json.loads((p / "summary.json").read_text())


LOADERS = {"model": _model, "bundle": _bundle, "export": _export, "csv": _csv, "png": _png,
           "json": _json, "observer": _observer, "results": _results, "sweep": _sweep,
           "npz": lambda p: __import__("numpy").load(p)}


# -- the campaign -----------------------------------------------------------------------------

def attempts(seed: int, ctx, verbs: list[str] | None = None) -> list[Attempt]:
    """Every registered generator's attempts (seeded), a verb without one getting the
    generic attempts of :func:`fault_attempts.generic`."""
    from fault_attempts import generic
    rng = random.Random(seed)
    from softgen.cli import VERBS
    out: list[Attempt] = []
    names = verbs or sorted(set(VERBS) | set(GENERATORS))
    for verb in names:
        gens = GENERATORS.get(verb)
        if gens:
            for g in gens:
                out.extend(g(rng, ctx))
        else:
            out.extend(generic(verb, rng, ctx))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--seed", type=int, default=36)
    p.add_argument("--verbs", default="", help="comma-separated verbs (default: all)")
    p.add_argument("--limit", type=int, default=0, help="run only the first N attempts")
    p.add_argument("--plugin", action="append", default=[], help="module that registers "
                   "more generators (@generator)")
    p.add_argument("--json", help="write every attempt's verdict here")
    p.add_argument("--list", action="store_true", help="list the attempts and exit")
    p.add_argument("--keep", help="sandbox root to keep (default: a temporary directory)")
    args = p.parse_args(argv)
    # The attempts' modules import this one by name: make that this very module.
    sys.modules.setdefault("fault_campaign", sys.modules[__name__])
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    for mod in ["fault_attempts", "fault_attempts_round3", *args.plugin]:
        importlib.import_module(mod)
    from fault_attempts import Context
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="softgen-campaign-"))
    root.mkdir(parents=True, exist_ok=True)
    ctx = Context(root / "inputs")
    todo = attempts(args.seed, ctx, [v for v in args.verbs.split(",") if v] or None)
    if args.limit:
        todo = todo[:args.limit]
    if args.list:
        for i, a in enumerate(todo):
            print(f"{i:4d} {a.verb:<10} {a.name}")
        print(f"{len(todo)} attempts")
        return 0
    cache = root / "cache"
    t0 = time.monotonic()
    results: list[Run] = [None] * len(todo)      # type: ignore[list-item]

    def one(i: int) -> None:
        try:
            results[i] = run_attempt(todo[i], ctx, root / "runs", i, cache)
        except Exception as exc:                 # noqa: BLE001 - the harness's own failure
            results[i] = Run(todo[i], None, "", "", 0.0, 0.0, [], [], "harness",
                             f"{type(exc).__name__}: {exc}")
        r = results[i]
        print(f"[{sum(x is not None for x in results)}/{len(todo)}] {r.verdict:<9} "
              f"{r.attempt.verb:<10} {r.attempt.name[:60]:<60} {r.seconds:5.1f} s  "
              f"{r.detail[:90]}", flush=True)
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        list(pool.map(one, range(len(todo))))
    report(results, time.monotonic() - t0, args)
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0


def report(results: list[Run], seconds: float, args) -> None:
    by_verb: dict[str, Counter] = defaultdict(Counter)
    for r in results:
        by_verb[r.attempt.verb][r.verdict] += 1
    kinds = ["clean", "traceback", "wrong", "lost", "orphan", "silent", "hang", "crash",
             "harness"]
    print()
    print(f"{'verb':<12}" + "".join(f"{k:>10}" for k in ["attempts"] + kinds))
    for verb, c in sorted(by_verb.items()):
        print(f"{verb:<12}{sum(c.values()):>10}" + "".join(f"{c[k]:>10}" for k in kinds))
    total = Counter(r.verdict for r in results)
    n = len(results)
    print(f"{'all':<12}{n:>10}" + "".join(f"{total[k]:>10}" for k in kinds))
    print(f"\nclean: {total['clean']} of {n} ({100 * total['clean'] / max(n, 1):.1f} %), "
          f"{seconds:.0f} s wall, {args.jobs} jobs, seed {args.seed}")
    unclean = [r for r in results if r.verdict != "clean"]
    if unclean:
        print("\nunclean:")
        for r in unclean:
            print(f"  {r.verdict:<9} {r.attempt.verb:<10} {r.attempt.name[:60]:<60} "
                  f"{r.detail[:120]}")
    if args.json:
        Path(args.json).write_text(json.dumps([
            {"verb": r.attempt.verb, "name": r.attempt.name, "argv": r.attempt.argv,
             "verdict": r.verdict, "detail": r.detail, "status": r.status,
             "seconds": round(r.seconds, 2), "stderr": r.stderr[-2000:]}
            for r in results], indent=1))


if __name__ == "__main__":
    sys.exit(main())
