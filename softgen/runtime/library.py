"""Load a generated bundle and call its functions with numpy arrays.

The one loader module (DESIGN.md section 3 item 6). Each function gets
preallocated, column-major input and output buffers fixed once in CasADi's
``buffer()`` evaluator, so a call goes straight into the compiled library.
Two ways to call:

``f(q, qd, ...)``
    Convenient: checks shapes, copies the inputs in, returns fresh arrays
    (column vectors as 1-D arrays).
``f.inputs[i][...] = ...; f.call(); f.outputs[j]``
    Fast path for loops: no checks, no allocation (overhead measured by
    ``softgen bench``).

Every C return code is checked. Without a C compiler the bundle falls back to
CasADi's own evaluation of the same functions, with a warning.
"""
from __future__ import annotations

import warnings
from pathlib import Path
import casadi as ca
import numpy as np

from ..codegen.build import build, check_source, find_compiler, library_path, read_manifest
from ..errors import BundleError, ShapeError

class BundleFunction:
    """One function of a bundle with preallocated buffers, evaluated by CasADi.

    ``function`` is either ``casadi.external`` of the compiled library (backend
    "c") or the symbolic casadi.Function itself (backend "casadi"); both are run
    through CasADi's ``buffer()`` evaluator, which calls straight into the
    function with pointers fixed once (a plain ctypes call costs 0.5-1 µs here,
    this path about 0.2 µs, see ``softgen bench``).

    Column-vector inputs and outputs are 1-D arrays; matrices are 2-D,
    column-major views of the same memory.
    """

    def __init__(self, function, sig: dict):
        self.function = function
        self.name = function.name()
        self.in_names = [i["name"] for i in sig["inputs"]]
        self.out_names = [o["name"] for o in sig["outputs"]]
        self.in_shapes = [tuple(i["shape"]) for i in sig["inputs"]]
        self.out_shapes = [tuple(o["shape"]) for o in sig["outputs"]]
        for k, shape in enumerate(self.in_shapes):
            if function.size_in(k) != shape:
                raise BundleError(f"{self.name}: input {self.in_names[k]!r} has shape "
                                  f"{function.size_in(k)} in the library but {shape} in "
                                  "manifest.json; regenerate the bundle")
        flat_in = [np.zeros(r * c) for r, c in self.in_shapes]
        flat_out = [np.zeros(r * c) for r, c in self.out_shapes]
        self.inputs = [_view(f, s) for f, s in zip(flat_in, self.in_shapes)]
        self.outputs = [_view(f, s) for f, s in zip(flat_out, self.out_shapes)]
        self._flat_in = flat_in
        self._flat_out = flat_out
        self._bound: dict[int, np.ndarray] = {}
        self._expect = [(r,) if c == 1 else (r, c) for r, c in self.in_shapes]
        # Assigning into a memoryview copies and checks shape and dtype in one C-level
        # step (~0.1 µs against ~0.5 µs for numpy's check + setitem); it only takes
        # 1-D targets, so functions with matrix inputs use the numpy path.
        self._in_mv = ([memoryview(f) for f in flat_in]
                       if all(c == 1 for _, c in self.in_shapes) else None)
        buf, self._eval = function.buffer()
        for i, b in enumerate(flat_in):
            buf.set_arg(i, memoryview(b))
        for i, b in enumerate(flat_out):
            buf.set_res(i, memoryview(b))
        self._buf = buf        # the evaluator points into it: keep it alive
        self.can_fail = bool(sig.get("can_fail", True))
        # Reading the return code through SWIG costs 1.4 µs, six times a small call.
        # It is read on every call of a function whose C can return non-zero
        # (manifest "can_fail"); the others are straight-line SX code whose only
        # exit is `return 0`, so there is nothing to read.
        self.call = self.checked_call if self.can_fail else self._eval
        self.checked_call()     # probe once: a broken library fails here, not in a loop

    def bind_output(self, k: int, array: np.ndarray) -> None:
        """Make the next calls write output ``k`` into ``array`` (no copy afterwards).

        ``array`` must be C-contiguous float64 with exactly as many entries as the
        output: a block of rows of a (samples × signals) array is the (signals ×
        samples) column-major layout the C writes. It stays bound until bound again.
        """
        if not (isinstance(array, np.ndarray) and array.dtype == np.float64
                and array.flags.c_contiguous and array.size == self._flat_out[k].size):
            raise ShapeError(f"{self.name}: output {self.out_names[k]!r} needs a C-contiguous "
                             f"float64 array of {self._flat_out[k].size} entries")
        self._buf.set_res(k, memoryview(array.reshape(-1)))
        self._bound[k] = array          # the evaluator points into it: keep it alive

    def call(self) -> None:  # replaced per instance (see __init__)
        """Evaluate on the current input buffers into the output buffers."""

    def checked_call(self) -> None:
        """:meth:`call`, then raise if the C function returned non-zero."""
        self._eval()
        ret = self._buf.ret()
        if ret != 0:
            raise BundleError(f"{self.name} returned error code {ret}")

    def __call__(self, *args):
        """Evaluate on ``args`` (shapes checked); returns fresh arrays."""
        if len(args) != len(self.inputs):
            raise ShapeError(f"{self.name}: expected {len(self.inputs)} inputs "
                             f"({', '.join(self.in_names)}), got {len(args)}")
        if not self._load_fast(args):
            for k, a in enumerate(args):   # lists, columns, ints, matrices; or the error
                self._load_slow(k, a)
        self.call()
        if len(self.outputs) == 1:
            return self.outputs[0].copy()
        return tuple(o.copy() for o in self.outputs)

    def _load_fast(self, args: tuple) -> bool:
        """Copy float64 1-D arrays of the right lengths in; False if any is not one."""
        if self._in_mv is None:
            return False
        try:
            for mv, a in zip(self._in_mv, args):
                mv[:] = a     # checks length and dtype in C: ValueError/TypeError otherwise
        except (ValueError, TypeError):
            return False
        return True

    def _load_slow(self, k: int, a) -> None:
        try:
            a = np.asarray(a, dtype=float)
        except (TypeError, ValueError):
            raise ShapeError(f"{self.name}: input {self.in_names[k]!r} expected numbers "
                             f"of shape {self._expect[k]}, got {type(a).__name__}") from None
        r, c = self.in_shapes[k]
        if a.shape == (r, c) or (c == 1 and a.size == r and a.ndim <= 1):
            self.inputs[k][...] = a.reshape(self.inputs[k].shape, order="F")
        else:
            raise ShapeError(f"{self.name}: input {self.in_names[k]!r} expected shape "
                             f"{self._expect[k]}, got {a.shape}")


def _view(flat: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    r, c = shape
    return flat if c == 1 else flat.reshape((r, c), order="F")


class Bundle:
    """A generated model bundle: its manifest and callable functions.

    Functions are reachable as ``bundle["planar_2link_regressor"]`` or by quantity,
    ``bundle.regressor``.

    Parameters
    ----------
    path
        Bundle directory (``generated/<model>``).
    build
        Compile the library if it is not there yet (needs a C compiler).
    backend
        ``"auto"`` (compiled library, else CasADi with a warning), ``"c"`` (compiled
        library or error) or ``"casadi"``.
    """

    def __init__(self, path: Path, *, build_missing: bool = True, backend: str = "auto",
                 cc: str | None = None):
        if backend not in ("auto", "c", "casadi"):
            raise ValueError(f"backend: expected 'auto', 'c' or 'casadi', got {backend!r}")
        self.path = Path(path)
        if not self.path.is_dir():
            raise BundleError(f"{self.path}: no such bundle directory; run "
                              f"`softgen generate {self.path.name}`")
        self.manifest = read_manifest(self.path)
        self.name = self.manifest["model"]
        check_source(self.path, self.manifest)
        _check_model_unchanged(self.manifest)
        self.parameter_names = list(self.manifest["parameters"]["names"])
        self.parameter_nominal = np.array(self.manifest["parameters"]["nominal"], dtype=float)
        self.build_seconds = 0.0
        if backend == "casadi":
            self.backend = "casadi"
        else:
            lib = library_path(self.path, self.manifest)
            if not lib.exists() and (not build_missing or find_compiler(cc) is None):
                if backend == "c" or not build_missing:
                    raise BundleError(f"{lib}: compiled library missing" + (
                        "" if build_missing else " (build_missing=False)")
                        + "; run `softgen generate " + self.name + "` with a C compiler")
                warnings.warn(f"{self.name}: no C compiler found (install gcc or set CC); "
                              "evaluating with CasADi instead, slower", RuntimeWarning,
                              stacklevel=2)
                self.backend = "casadi"
            else:
                if not lib.exists():
                    lib, self.build_seconds = build(self.path, cc=cc)
                self.backend = "c"
                self.library = lib
        self.functions = self._load()

    def _load(self) -> dict[str, BundleFunction]:
        sigs = self.manifest["functions"]
        if self.backend == "c":
            fns = {}
            for name in sigs:
                try:
                    fns[name] = ca.external(name, str(self.library))
                except RuntimeError as exc:
                    raise BundleError(f"{self.library}: cannot load {name!r} "
                                      f"({str(exc).splitlines()[-1]}); regenerate the "
                                      "bundle") from None
        else:
            from ..bundle import casadi_functions  # the symbolic layer, only for the fallback
            fns = casadi_functions(self.manifest)
        return {name: BundleFunction(fns[name], sig) for name, sig in sigs.items()}

    def __getitem__(self, name: str):
        try:
            return self.functions[name]
        except KeyError:
            raise KeyError(f"{self.name}: no function {name!r} (have: "
                           f"{', '.join(self.functions)})") from None

    def __getattr__(self, quantity: str):
        functions = self.__dict__.get("functions", {})
        full = f"{self.__dict__.get('name')}_{quantity}"
        if full in functions:
            return functions[full]
        raise AttributeError(f"bundle has no function {full!r}")

    def __repr__(self) -> str:
        return f"Bundle({self.name!r}, backend={self.backend!r}, functions={list(self.functions)})"


def _check_model_unchanged(manifest: dict) -> None:
    """Refuse a bundle generated from an older version of its model file."""
    from ..bundle import identity_hash
    current = identity_hash(manifest)
    if current is not None and current != manifest["hash"]:
        raise BundleError(f"generated/{manifest['model']} is stale: {manifest['model_file']} "
                          f"changed since it was generated; run `softgen generate "
                          f"{manifest['model']}`")


def load_bundle(name_or_path: str | Path, *, generated_root: Path | None = None,
                **kwargs) -> Bundle:
    """Load ``generated/<model>`` (or a bundle directory path)."""
    from ..bundle import GENERATED_DIR
    p = Path(name_or_path)
    if not p.is_dir():
        p = Path(generated_root or GENERATED_DIR) / str(name_or_path)
    return Bundle(p, **kwargs)

