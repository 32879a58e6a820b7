"""Load a generated bundle and call its functions with numpy arrays.

The one loader module (docs/design.md section 3 item 6). Each function gets
preallocated, column-major input and output buffers fixed once in CasADi's
``buffer()`` evaluator, so a call goes straight into the compiled library.
Two ways to call:

``f(q, qd, ...)``
    Convenient: checks shapes, copies the inputs in, returns fresh arrays
    (column vectors as 1-D arrays). For a compiled library, float64 1-D arrays of
    the right lengths are copied, evaluated and returned by one C call
    (:mod:`softgen.runtime.fastcall`, ~0.5 µs for the Panda's τ); anything else
    goes through the Python checks, which convert it or give the error.
``f.inputs[i][...] = ...; f.call(); f.outputs[j]``
    Fast path for loops: no checks, no allocation (overhead measured by
    ``softgen bench``). Bind ``ins, call, outs = f.inputs, f.call, f.outputs``
    once before the loop. Each thread gets its own buffers (issue 16: two threads
    used to read each other's results); ``inputs`` and ``outputs`` are tuples,
    so rebinding a buffer (``f.inputs[0] = x``) raises instead of being ignored.

Before loading, the manifest is checked against its schema
(:mod:`softgen.codegen.manifest`), the C source and the model file against the
manifest, the compiled library against its build record
(:func:`softgen.codegen.build.verify_library`; rebuilt when it does not match),
and the parameter vector against the library (``Y @ nominal ==
inverse_dynamics`` at a seeded state).

Every C return code is checked. Without a C compiler the bundle falls back to
CasADi's own evaluation of the same functions, with a warning.
"""
from __future__ import annotations

import ctypes
import functools
import threading
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

from softgen.codegen.build import (check_source, ensure_library, find_compiler, library_path,
                             read_manifest, verify_library)
from softgen.core.errors import BundleError, ShapeError
from softgen.runtime import fastcall

_get_ident = threading.get_ident

class _Buffers(tuple):
    """The fixed buffers of a function: fill them in place, never rebind them.

    ``f.inputs[0] = q`` on a list would replace the list entry and leave the
    buffer the library reads untouched (a silent no-op, issue 16); here it raises.
    """

    __slots__ = ()

    def __setitem__(self, key, value):
        raise TypeError("bundle buffers are fixed: copy into them with "
                        "f.inputs[i][:] = value (or [...] for matrices), do not rebind them")


class _ThreadState:
    """One thread's input and output buffers and the evaluator bound to them."""

    __slots__ = ("inputs", "outputs", "flat_in", "flat_out", "bound", "in_mv", "buf", "eval",
                 "call")


class BundleFunction:
    """One function of a bundle with preallocated buffers, evaluated by CasADi.

    ``function`` is either ``casadi.external`` of the compiled library (backend
    "c") or the symbolic casadi.Function itself (backend "casadi"); both are run
    through CasADi's ``buffer()`` evaluator, which calls straight into the
    function with pointers fixed once (a plain ctypes call costs 0.5-1 µs here,
    this path about 0.2 µs, see ``softgen bench``).

    Column-vector inputs and outputs are 1-D arrays; matrices are 2-D,
    column-major views of the same memory.

    Threads: the buffers belong to a thread. ``inputs``, ``outputs`` and ``call``
    give the calling thread's own set (created on its first use), so two threads
    calling the same function, either way, never see each other's results. A
    thread that binds ``ins = f.inputs`` must use them with that thread's
    ``f.call``; ``inputs`` and ``outputs`` are tuples that cannot be rebound.
    """

    def __init__(self, function, sig: dict, library: Path | None = None):
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
        for k, shape in enumerate(self.out_shapes):
            if function.size_out(k) != shape:
                raise BundleError(f"{self.name}: output {self.out_names[k]!r} has shape "
                                  f"{function.size_out(k)} in the library but {shape} in "
                                  "manifest.json; regenerate the bundle")
        self._expect = [(r,) if c == 1 else (r, c) for r, c in self.in_shapes]
        self.can_fail = bool(sig.get("can_fail", True))
        self.doc = str(sig.get("doc", ""))
        self._owner = threading.get_ident()
        self._local = threading.local()
        self._main = self._new_state()
        self._main.call()     # probe once: a broken library fails here, not in a loop
        self._fast = _fast_call(self._main, self._owner, self._checked)
        #: The compiled entry (:mod:`softgen.runtime.fastcall`), or None.
        self._cfast = (None if self._fast is None or library is None
                       else _c_call(self, self._main, library, self._fast))
        #: Which entry ``f(...)`` runs first: "c" (the compiled checked call), "python"
        #: (the generated Python entry) or "checked" (matrix inputs: the checks first).
        self.fast_path = ("c" if self._cfast is not None else
                          "python" if self._fast is not None else "checked")
        if self._fast is not None:
            # Python looks ``__call__`` up on the type: a class of this instance's own
            # whose ``__call__`` is the fast entry saves the method frame (~250 ns of a
            # 1.2 µs call of the Panda's τ).
            entry = self._cfast if self._cfast is not None else self._fast
            self.__class__ = type(BundleFunction.__name__, (BundleFunction,),
                                  {"__call__": staticmethod(entry),
                                   "__doc__": BundleFunction.__doc__})

    def _new_state(self) -> _ThreadState:
        st = _ThreadState()
        flat_in = [np.zeros(r * c) for r, c in self.in_shapes]
        flat_out = [np.zeros(r * c) for r, c in self.out_shapes]
        st.inputs = _Buffers(_view(f, s) for f, s in zip(flat_in, self.in_shapes))
        st.outputs = _Buffers(_view(f, s) for f, s in zip(flat_out, self.out_shapes))
        st.flat_in = flat_in
        st.flat_out = flat_out
        st.bound = {}
        # Assigning into a memoryview copies and checks shape and dtype in one C-level
        # step (~0.1 µs against ~0.5 µs for numpy's check + setitem); it only takes
        # 1-D targets, so functions with matrix inputs use the numpy path.
        st.in_mv = ([memoryview(f) for f in flat_in]
                    if all(c == 1 for _, c in self.in_shapes) else None)
        buf, st.eval = self.function.buffer()
        for i, b in enumerate(flat_in):
            buf.set_arg(i, memoryview(b))
        for i, b in enumerate(flat_out):
            buf.set_res(i, memoryview(b))
        st.buf = buf        # the evaluator points into it: keep it alive
        # Reading the return code through SWIG costs 1.4 µs, six times a small call.
        # It is read on every call of a function whose C can return non-zero
        # (manifest "can_fail"); the others are straight-line SX code whose only
        # exit is `return 0`, so there is nothing to read.
        if self.can_fail:
            name, ev = self.name, st.eval

            def checked() -> None:
                ev()
                ret = buf.ret()
                if ret != 0:
                    raise BundleError(f"{name} returned error code {ret}")
            st.call = checked
        else:
            st.call = st.eval
        return st

    def _state(self) -> _ThreadState:
        if _get_ident() == self._owner:
            return self._main
        st = getattr(self._local, "state", None)
        if st is None:
            st = self._local.state = self._new_state()
        return st

    @property
    def inputs(self) -> tuple:
        """The calling thread's input buffers (fill in place: ``f.inputs[i][:] = x``)."""
        if _get_ident() == self._owner:     # the common case, kept short
            return self._main.inputs
        return self._state().inputs

    @inputs.setter
    def inputs(self, value) -> None:
        raise AttributeError(f"{self.name}: inputs cannot be rebound; copy into the "
                             "buffers with f.inputs[i][:] = value")

    @property
    def outputs(self) -> tuple:
        """The calling thread's output buffers (overwritten by every call)."""
        if _get_ident() == self._owner:     # the common case, kept short
            return self._main.outputs
        return self._state().outputs

    @outputs.setter
    def outputs(self, value) -> None:
        raise AttributeError(f"{self.name}: outputs cannot be rebound")

    @property
    def call(self):
        """Evaluate the calling thread's input buffers into its output buffers."""
        if _get_ident() == self._owner:     # the common case, kept short
            return self._main.call
        return self._state().call

    def bind_output(self, k: int, array: np.ndarray) -> None:
        """Make the calling thread's next calls write output ``k`` into ``array``.

        No copy afterwards: ``array`` must be C-contiguous float64 with exactly as many
        entries as the output (a block of rows of a (samples × signals) array is the
        (signals × samples) column-major layout the C writes). It stays bound until
        bound again; ``outputs[k]`` is then not written.
        """
        st = self._state()
        if not (isinstance(array, np.ndarray) and array.dtype == np.float64
                and array.flags.c_contiguous and array.size == st.flat_out[k].size):
            raise ShapeError(f"{self.name}: output {self.out_names[k]!r} needs a C-contiguous "
                             f"float64 array of {st.flat_out[k].size} entries")
        flat = array.reshape(-1)
        st.buf.set_res(k, memoryview(flat))
        if st is self._main and self._cfast is not None:
            self._cfast.set_res(k, flat)
        st.bound[k] = array          # the evaluator points into it: keep it alive

    def release_output(self, k: int) -> None:
        """Write output ``k`` into ``outputs[k]`` again (and let a bound array go)."""
        st = self._state()
        st.buf.set_res(k, memoryview(st.flat_out[k]))
        if st is self._main and self._cfast is not None:
            self._cfast.set_res(k, st.flat_out[k])
        st.bound.pop(k, None)

    def checked_call(self) -> None:
        """:meth:`call`, then raise if the C function returned non-zero."""
        st = self._state()
        st.eval()
        ret = st.buf.ret()
        if ret != 0:
            raise BundleError(f"{self.name} returned error code {ret}")

    def __call__(self, *args):
        """Evaluate on ``args`` (shapes checked); returns fresh arrays.

        The owner thread's float64 1-D arrays of the right lengths take a straight path,
        installed as the instance's own ``__call__``: with a compiled library the C entry
        of :mod:`softgen.runtime.fastcall` (contiguous arrays; ``fast_path == "c"``),
        else, and for whatever the C entry does not take, :func:`_fast_call` (one
        memoryview copy per input, the evaluator, one copy per output); anything else,
        or a wrong shape, goes through the checks of :meth:`_checked`, which give the
        error. Every path returns the same arrays and raises the same errors."""
        # Functions with vector inputs only never get here: their instances call the
        # fast entry directly (:func:`_fast_call`), which falls back on the checks.
        return self._checked(args)

    @property
    def signature(self) -> str:
        """``name(q[7], qd[7]) -> (tau[7])``: inputs and outputs with their shapes."""
        def one(n, shape):
            r, c = shape
            return f"{n}[{r}]" if c == 1 else f"{n}[{r}x{c}]"
        ins = ", ".join(one(n, s) for n, s in zip(self.in_names, self.in_shapes))
        outs = ", ".join(one(n, s) for n, s in zip(self.out_names, self.out_shapes))
        return f"{self.name}({ins}) -> ({outs})"

    def __repr__(self) -> str:
        return f"<{self.signature}{': ' + self.doc if self.doc else ''}>"

    def _checked(self, args: tuple):
        st = self._state()
        if len(args) != len(st.inputs):
            raise ShapeError(f"{self.name}: expected {len(st.inputs)} inputs "
                             f"({', '.join(self.in_names)}), got {len(args)}")
        if not self._load_fast(st, args):
            for k, a in enumerate(args):   # lists, columns, ints, matrices; or the error
                self._load_slow(st, k, a)
        st.call()
        if len(st.outputs) == 1:
            return st.outputs[0].copy()
        return tuple(o.copy() for o in st.outputs)

    @staticmethod
    def _load_fast(st: _ThreadState, args: tuple) -> bool:
        """Copy float64 1-D arrays of the right lengths in; False if any is not one."""
        if st.in_mv is None:
            return False
        try:
            for mv, a in zip(st.in_mv, args):
                mv[:] = a     # checks length and dtype in C: ValueError/TypeError otherwise
        except (ValueError, TypeError):
            return False
        return True

    def _load_slow(self, st: _ThreadState, k: int, a) -> None:
        try:
            a = np.asarray(a, dtype=float)
        except (TypeError, ValueError):
            raise ShapeError(f"{self.name}: input {self.in_names[k]!r} expected numbers "
                             f"of shape {self._expect[k]}, got {type(a).__name__}") from None
        r, c = self.in_shapes[k]
        if a.shape == (r, c) or (c == 1 and a.size == r and a.ndim <= 1):
            st.inputs[k][...] = a.reshape(st.inputs[k].shape, order="F")
        else:
            raise ShapeError(f"{self.name}: input {self.in_names[k]!r} expected shape "
                             f"{self._expect[k]}, got {a.shape}")


#: A missing argument of a fast entry (it fails the memoryview copy, so the checked path
#: runs and names the arity).
_NO = object()

_ENTRY = """
def entry({params}, *rest):
    if not rest and get_ident() == owner:
        try:
{copies}
        except (ValueError, TypeError):
            pass
        else:
            {call}
            return result()
    return checked(tuple(a for a in ({args},) if a is not NO) + rest)
"""


def _fast_call(st: _ThreadState, owner: int, checked):
    """The straight path of a function whose inputs are all vectors: the entry point
    ``f(*args)`` itself, a closure of the function's arity (one Python frame per call:
    installed as the instance's ``__call__``, :meth:`BundleFunction._install_fast`) that,
    on the owner thread, copies each argument into its buffer through a memoryview
    (length and dtype checked in C: ValueError/TypeError otherwise), evaluates, and
    returns fresh copies of the outputs; any other call goes to ``checked(args)``, which
    gives the error. The arity is written out (a loop over the inputs cost more than
    the evaluation of the Panda's τ; issue 31: the checked call must not be slower than
    the peers' calls from Python, ≤ 1 µs). None for matrix inputs."""
    if st.in_mv is None:
        return None
    mv, outs = st.in_mv, st.outputs
    if len(outs) == 1:
        result = outs[0].copy            # a bound builtin: no Python frame per call
    else:
        def result():
            return tuple(o.copy() for o in outs)
    n = len(mv)
    names = [f"a{i}" for i in range(n)]
    call = st.call
    # CasADi's evaluator is a partial of a builtin and its handle: called directly it
    # saves the partial's layer; a prebuilt slice saves building one per copy (~85 ns
    # of the 1.1 µs Panda τ together).
    direct = (isinstance(call, functools.partial) and len(call.args) == 1
              and not call.keywords)
    src = _ENTRY.format(params=", ".join(f"{a}=NO" for a in names),
                        copies="\n".join(f"            m{i}[ALL] = a{i}" for i in range(n)),
                        args=", ".join(names),
                        call="ev(handle)" if direct else "call()")
    scope = {f"m{i}": m for i, m in enumerate(mv)}
    scope.update(get_ident=_get_ident, owner=owner, call=call, result=result,
                 checked=checked, NO=_NO, ALL=slice(None))
    if direct:
        scope.update(ev=call.func, handle=call.args[0])
    exec(compile(src, f"<softgen fast call, {n} inputs>", "exec"), scope)
    return scope["entry"]


def _c_call(f: BundleFunction, st: _ThreadState, library: Path, fallback):
    """The compiled checked call of ``f`` (:class:`softgen.runtime.fastcall` FastCall)
    on the owner's buffers ``st``, calling ``f.name`` of ``library`` directly with the
    pointers CasADi's evaluator passes; ``fallback`` (the Python entry) takes every call
    it does not. None when the extension cannot be built or the function has a sparse
    input or output (the buffers are dense)."""
    mod = fastcall.module()
    if mod is None:
        return None
    fn = f.function
    if any(fn.nnz_in(i) != r * c for i, (r, c) in enumerate(f.in_shapes)) or any(
            fn.nnz_out(i) != r * c for i, (r, c) in enumerate(f.out_shapes)):
        return None
    try:
        lib = ctypes.CDLL(str(library))
        c_fn = getattr(lib, f.name)
    except (OSError, AttributeError):
        return None
    sz = [ctypes.c_longlong(0) for _ in range(4)]
    work = getattr(lib, f"{f.name}_work", None)
    if work is not None:
        work.restype = ctypes.c_int
        if work(*(ctypes.byref(x) for x in sz)) != 0:
            return None
        sz_arg, sz_res, sz_iw, sz_w = (x.value for x in sz)
    else:
        sz_arg, sz_res, sz_iw, sz_w = len(f.in_shapes), len(f.out_shapes), 0, 0
    sz_arg, sz_res = max(sz_arg, len(f.in_shapes)), max(sz_res, len(f.out_shapes))
    mem, release = 0, None
    checkout = getattr(lib, f"{f.name}_checkout", None)
    if checkout is not None:
        checkout.restype = ctypes.c_int
        mem = checkout()
        if mem < 0:
            return None
        rel = getattr(lib, f"{f.name}_release", None)
        release = None if rel is None else ctypes.cast(rel, ctypes.c_void_p).value
    iw = np.zeros(max(sz_iw, 1), dtype=np.int64)
    w = np.zeros(max(sz_w, 1))
    on_error = None
    if f.can_fail:
        name = f.name

        def on_error(code: int):
            raise BundleError(f"{name} returned error code {code}")
    return mod.FastCall(ctypes.cast(c_fn, ctypes.c_void_p).value, release, mem, f._owner,
                        tuple(st.flat_in), tuple(st.flat_out), tuple(st.outputs),
                        sz_arg, sz_res, iw, w, fallback, on_error,
                        (fn, lib, c_fn, iw, w, tuple(st.flat_in), tuple(st.flat_out)))


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
                 cc: str | None = None, model_check=None, fallback=None):
        if backend not in ("auto", "c", "casadi"):
            raise ValueError(f"backend: expected 'auto', 'c' or 'casadi', got {backend!r}")
        self.path = Path(path)
        if not self.path.is_dir():
            raise BundleError(f"{self.path}: no such bundle directory; run "
                              f"`softgen generate {self.path.name}`")
        self.manifest = read_manifest(self.path)      # schema-checked (codegen/manifest.py)
        self.name = self.manifest["model"]
        check_source(self.path, self.manifest)
        # The model-aware parts are given by the caller (softgen.bundles.bundle.load_bundle): the
        # runtime knows nothing of model files or the symbolic layer.
        if model_check is not None:
            model_check(self.manifest, self.path)
        self._fallback = fallback
        self.parameter_names = list(self.manifest["parameters"]["names"])
        self.parameter_nominal = np.array(self.manifest["parameters"]["nominal"], dtype=float)
        self.build_seconds = 0.0
        if backend == "casadi":
            self.backend = "casadi"
        else:
            self.backend = self._library(backend, build_missing, cc)
        self.functions = self._load()
        self._check_parameters()

    def _library(self, backend: str, build_missing: bool, cc: str | None) -> str:
        """Verify (or build) the compiled library; the backend to use."""
        lib = library_path(self.path, self.manifest)
        problem = verify_library(lib, self.manifest)
        if problem is None:
            self.library = lib
            return "c"
        can_build = build_missing and find_compiler(cc) is not None
        if not can_build:
            if backend == "c" or not build_missing:
                raise BundleError(f"{lib}: compiled library {problem}" + (
                    "" if build_missing else " (build_missing=False)")
                    + "; run `softgen generate " + self.name + "` with a C compiler")
            warnings.warn(f"{self.name}: compiled library {problem} and no C compiler found "
                          "(install gcc or set CC); evaluating with CasADi instead, slower",
                          RuntimeWarning, stacklevel=3)
            return "casadi"
        lib, self.build_seconds, repaired = ensure_library(self.path, cc=cc)
        if repaired:
            warnings.warn(f"{lib}: cached library {repaired}; rebuilt", RuntimeWarning,
                          stacklevel=3)
        problem = verify_library(lib, self.manifest)
        if problem is not None:   # e.g. another process replaced it again in between
            raise BundleError(f"{lib}: compiled library {problem} after rebuilding; "
                              f"run `softgen generate {self.name}`")
        self.library = lib
        return "c"

    def _check_parameters(self, rtol: float = 1e-8) -> None:
        """``Y @ parameters.nominal (+ known torque) == inverse_dynamics`` at a seeded state.

        The parameter vector is data in the manifest, the dynamics are compiled
        code: an edited number would make every adaptive law start from a wrong
        π without a word (issue 16).
        """
        m = self.name
        Y_f = self.functions.get(f"{m}_regressor")
        tau_f = self.functions.get(f"{m}_inverse_dynamics")
        if Y_f is None or tau_f is None or Y_f.in_shapes != tau_f.in_shapes:
            return
        rng = np.random.default_rng(16)
        args = [rng.uniform(-1.0, 1.0, r if c == 1 else (r, c)) for r, c in Y_f.in_shapes]
        Y = np.atleast_2d(Y_f(*args))
        if Y.shape[1] != self.parameter_nominal.size:
            raise BundleError(f"{self.path / 'manifest.json'}: parameters.nominal: expected "
                              f"{Y.shape[1]} values (columns of {m}_regressor), got "
                              f"{self.parameter_nominal.size}; regenerate the bundle")
        tau = np.ravel(tau_f(*args))
        pred = Y @ self.parameter_nominal
        known = self.functions.get(f"{m}_known_torque")
        if known is not None and known.in_shapes == Y_f.in_shapes:
            pred = pred + np.ravel(known(*args))
        scale = np.abs(Y) @ np.abs(self.parameter_nominal) + np.abs(tau) + 1e-12
        err = np.abs(pred - tau)
        if not np.all(err <= rtol * scale):
            j = int(np.argmax(err / scale))
            raise BundleError(f"{self.path / 'manifest.json'}: parameters.nominal: Y @ nominal "
                              f"differs from {m}_inverse_dynamics (component {j + 1}: "
                              f"{pred[j]:.6g} vs {tau[j]:.6g}) at a seeded state; the manifest "
                              f"was edited or is stale, run `softgen generate {m}`")

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
            if self._fallback is None:
                raise BundleError(f"{self.name}: no compiled library and no way to rebuild the "
                                  "functions here; load it with softgen.bundles.bundle.load_bundle")
            fns = self._fallback(self.manifest)
        lib = self.library if self.backend == "c" else None
        return {name: BundleFunction(fns[name], sig, lib) for name, sig in sigs.items()}

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

    def __dir__(self) -> list[str]:
        """The usual attributes and every function by quantity (``bundle.regressor``)."""
        pre = f"{self.name}_"
        short = [k[len(pre):] for k in self.functions if k.startswith(pre)]
        return sorted(set(super().__dir__()) | set(short))

    def __repr__(self) -> str:
        pre = f"{self.name}_"
        lines = [f"Bundle({self.name!r}, backend={self.backend!r}, path={str(self.path)!r}), "
                 f"{len(self.functions)} functions:"]
        lines += [f"  .{f.name[len(pre):] if f.name.startswith(pre) else f.name}: "
                  f"{f.signature}" for f in self.functions.values()]
        return "\n".join(lines)
