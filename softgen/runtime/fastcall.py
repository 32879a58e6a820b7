"""The checked call of a compiled bundle function, done in C (issue 31 item 6).

A bundle function's convenient call ``f(q, qd, ...)`` copies its inputs into the
function's fixed input buffers, evaluates, and returns fresh copies of the outputs
(:mod:`softgen.runtime.library`). In Python that is a frame, a memoryview copy per
input, CasADi's buffer evaluator and a ``copy()`` per output: 1.0-1.1 µs for the
Panda's τ, of which 0.18 µs is the C. :class:`FastCall` does the same steps in one C
call, for the one case that is common: on the thread that owns the buffers, every
argument a C-contiguous, aligned, native float64 1-D numpy array of the input's
length, no keywords. Anything else (a list, ints, a column, a strided view, a wrong
shape or count, another thread) is handed unchanged to ``fallback``, the Python
entry, which checks it and gives the error, so what a call accepts, returns and
refuses is the Python path's in every case.

On that common case it does what the Python path does, in the same order: copy each
argument into the input buffer the library reads, call the compiled function (the
same pointers CasADi's evaluator passes: input buffers, output buffers, the
function's own work arrays, a memory slot checked out once; without the GIL, as
CasADi's evaluator, so other threads run during a long call), raise through
``on_error(code)`` when a function that can fail returns non-zero, and return
``out.copy()`` of each output buffer view (C order, as ``ndarray.copy``).

The extension is compiled once per Python, NumPy and source version with the bundle's
C compiler and cached under :func:`softgen.core.paths.cache_dir`; without a
compiler, Python headers or NumPy headers :func:`module` is None and bundles keep the
Python entry (``BundleFunction.fast_path`` says which one a function uses).
``SOFTGEN_FASTCALL=0`` turns it off.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import sysconfig
import tempfile
from pathlib import Path

__all__ = ["module", "SOURCE"]

SOURCE = r"""
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <pythread.h>
#include <stddef.h>
#include <string.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

typedef int (*casadi_fn)(const double **, double **, long long *, double *, int);
typedef void (*release_fn)(int);

typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    casadi_fn fn;
    release_fn release;
    int mem;
    unsigned long owner;
    Py_ssize_t n_in, n_out;
    Py_ssize_t *in_bytes;      /* bytes of each input */
    double **arg;              /* sz_arg pointers: the input buffers, then NULL */
    double **res;              /* sz_res pointers: the output buffers, then NULL */
    long long *iw;
    double *w;
    PyObject **results;        /* the output views copied into the returned arrays */
    PyObject *fallback;        /* the Python entry: every call not taken here */
    PyObject *on_error;        /* None, or on_error(code) raises */
    PyObject *keep;            /* what owns the memory pointed to */
} FastCall;

static PyObject *
fc_vectorcall(FastCall *self, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    Py_ssize_t n = PyVectorcall_NARGS(nargsf), i;
    if (self->fallback == NULL) {          /* cleared by the garbage collector */
        PyErr_SetString(PyExc_RuntimeError, "bundle function called after it was freed");
        return NULL;
    }
    if (kwnames != NULL || n != self->n_in || PyThread_get_thread_ident() != self->owner)
        goto fallback;
    for (i = 0; i < n; i++) {
        PyArrayObject *a = (PyArrayObject *)args[i];
        if (!PyArray_Check(args[i]) || PyArray_TYPE(a) != NPY_DOUBLE || PyArray_NDIM(a) != 1
            || PyArray_NBYTES(a) != self->in_bytes[i] || !PyArray_ISCARRAY_RO(a)
            || !PyArray_ISNOTSWAPPED(a))
            goto fallback;
    }
    for (i = 0; i < n; i++)
        memcpy(self->arg[i], PyArray_DATA((PyArrayObject *)args[i]), self->in_bytes[i]);
    {
        int ret;
        /* Other threads run meanwhile, as during CasADi's evaluator: a long loop must not
           stop them. The inputs are copied already; the buffers are this thread's. */
        Py_BEGIN_ALLOW_THREADS
        ret = self->fn((const double **)self->arg, self->res, self->iw, self->w, self->mem);
        Py_END_ALLOW_THREADS
        if (ret != 0 && self->on_error != Py_None) {
            PyObject *code = PyLong_FromLong(ret), *r;
            if (code == NULL) return NULL;
            r = PyObject_CallOneArg(self->on_error, code);
            Py_DECREF(code);
            Py_XDECREF(r);
            if (!PyErr_Occurred())
                PyErr_Format(PyExc_RuntimeError, "compiled function returned %d", ret);
            return NULL;
        }
    }
    if (self->n_out == 1)
        return PyArray_NewCopy((PyArrayObject *)self->results[0], NPY_CORDER);
    {
        PyObject *t = PyTuple_New(self->n_out);
        if (t == NULL) return NULL;
        for (i = 0; i < self->n_out; i++) {
            PyObject *c = PyArray_NewCopy((PyArrayObject *)self->results[i], NPY_CORDER);
            if (c == NULL) { Py_DECREF(t); return NULL; }
            PyTuple_SET_ITEM(t, i, c);
        }
        return t;
    }
fallback:
    return PyObject_Vectorcall(self->fallback, args, nargsf, kwnames);
}

static void *
address(PyObject *o)
{
    void *p = PyLong_AsVoidPtr(o);
    return p;
}

/* FastCall(fn, release, mem, owner, inputs, outputs, results, sz_arg, sz_res, iw, w,
            fallback, on_error, keep)
   fn, release: addresses (release 0: none); inputs, outputs: tuples of the float64
   buffers the library reads and writes; results: tuple of the arrays to copy out;
   iw (int64) and w (float64): work arrays, None when empty. */
static PyObject *
fc_new(PyTypeObject *type, PyObject *args, PyObject *kw)
{
    PyObject *fn, *rel, *ins, *outs, *results, *iw, *w, *fallback, *on_error, *keep;
    int mem;
    unsigned long owner;
    Py_ssize_t sz_arg, sz_res, i;
    FastCall *self;
    if (kw != NULL && PyDict_GET_SIZE(kw)) {
        PyErr_SetString(PyExc_TypeError, "FastCall takes positional arguments only");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "OOikO!O!O!nnOOOOO", &fn, &rel, &mem, &owner,
                          &PyTuple_Type, &ins, &PyTuple_Type, &outs, &PyTuple_Type, &results,
                          &sz_arg, &sz_res, &iw, &w, &fallback, &on_error, &keep))
        return NULL;
    if (PyTuple_GET_SIZE(outs) != PyTuple_GET_SIZE(results) || sz_arg < PyTuple_GET_SIZE(ins)
        || sz_res < PyTuple_GET_SIZE(outs) || !PyCallable_Check(fallback)) {
        PyErr_SetString(PyExc_ValueError, "FastCall: inconsistent arguments");
        return NULL;
    }
    self = PyObject_GC_New(FastCall, type);
    if (self == NULL) return NULL;
    self->vectorcall = (vectorcallfunc)fc_vectorcall;
    self->n_in = PyTuple_GET_SIZE(ins);
    self->n_out = PyTuple_GET_SIZE(outs);
    self->in_bytes = NULL; self->arg = NULL; self->res = NULL; self->results = NULL;
    self->fallback = Py_NewRef(fallback);
    self->on_error = Py_NewRef(on_error);
    self->keep = Py_NewRef(keep);
    self->mem = mem;
    self->owner = owner;
    self->fn = (casadi_fn)address(fn);
    self->release = rel == Py_None ? NULL : (release_fn)address(rel);
    self->in_bytes = PyMem_Calloc(self->n_in + 1, sizeof(Py_ssize_t));
    self->arg = PyMem_Calloc(sz_arg + 1, sizeof(double *));
    self->res = PyMem_Calloc(sz_res + 1, sizeof(double *));
    self->results = PyMem_Calloc(self->n_out + 1, sizeof(PyObject *));
    self->iw = NULL; self->w = NULL;
    PyObject_GC_Track(self);
    if (!self->in_bytes || !self->arg || !self->res || !self->results) {
        Py_DECREF(self);
        return PyErr_NoMemory();
    }
    if (PyErr_Occurred()) { Py_DECREF(self); return NULL; }
    for (i = 0; i < self->n_in + self->n_out; i++) {
        PyObject *o = i < self->n_in ? PyTuple_GET_ITEM(ins, i)
                                     : PyTuple_GET_ITEM(outs, i - self->n_in);
        PyArrayObject *a = (PyArrayObject *)o;
        if (!PyArray_Check(o) || PyArray_TYPE(a) != NPY_DOUBLE || !PyArray_ISCARRAY(a)
            || !PyArray_ISNOTSWAPPED(a)) {
            PyErr_SetString(PyExc_ValueError, "FastCall: buffers must be C-contiguous float64");
            Py_DECREF(self);
            return NULL;
        }
        if (i < self->n_in) {
            self->arg[i] = (double *)PyArray_DATA(a);
            self->in_bytes[i] = PyArray_NBYTES(a);
        } else {
            self->res[i - self->n_in] = (double *)PyArray_DATA(a);
        }
    }
    for (i = 0; i < self->n_out; i++) {
        PyObject *o = PyTuple_GET_ITEM(results, i);
        if (!PyArray_Check(o)) {
            PyErr_SetString(PyExc_ValueError, "FastCall: results must be arrays");
            Py_DECREF(self);
            return NULL;
        }
        self->results[i] = Py_NewRef(o);
    }
    if (iw != Py_None) {
        if (!PyArray_Check(iw) || PyArray_ITEMSIZE((PyArrayObject *)iw) != sizeof(long long)
            || !PyArray_ISCARRAY((PyArrayObject *)iw)) {
            PyErr_SetString(PyExc_ValueError, "FastCall: iw must be a C-contiguous int64 array");
            Py_DECREF(self);
            return NULL;
        }
        self->iw = (long long *)PyArray_DATA((PyArrayObject *)iw);
    }
    if (w != Py_None) {
        if (!PyArray_Check(w) || PyArray_TYPE((PyArrayObject *)w) != NPY_DOUBLE
            || !PyArray_ISCARRAY((PyArrayObject *)w)) {
            PyErr_SetString(PyExc_ValueError, "FastCall: w must be a C-contiguous float64 array");
            Py_DECREF(self);
            return NULL;
        }
        self->w = (double *)PyArray_DATA((PyArrayObject *)w);
    }
    return (PyObject *)self;
}

/* set_res(k, array): output k is written into array (bind_output), or back into its
   buffer; array must be C-contiguous float64 (checked by the caller for its size). */
static PyObject *
fc_set_res(FastCall *self, PyObject *args)
{
    Py_ssize_t k;
    PyObject *o;
    if (!PyArg_ParseTuple(args, "nO", &k, &o)) return NULL;
    if (k < 0 || k >= self->n_out || !PyArray_Check(o)
        || PyArray_TYPE((PyArrayObject *)o) != NPY_DOUBLE || !PyArray_ISCARRAY((PyArrayObject *)o)) {
        PyErr_SetString(PyExc_ValueError, "FastCall.set_res: bad output index or array");
        return NULL;
    }
    self->res[k] = (double *)PyArray_DATA((PyArrayObject *)o);
    Py_RETURN_NONE;
}

static int
fc_traverse(FastCall *self, visitproc visit, void *arg)
{
    Py_ssize_t i;
    Py_VISIT(self->fallback);
    Py_VISIT(self->on_error);
    Py_VISIT(self->keep);
    if (self->results)
        for (i = 0; i < self->n_out; i++) Py_VISIT(self->results[i]);
    return 0;
}

static int
fc_clear(FastCall *self)
{
    Py_ssize_t i;
    Py_CLEAR(self->fallback);
    Py_CLEAR(self->on_error);
    Py_CLEAR(self->keep);
    if (self->results)
        for (i = 0; i < self->n_out; i++) Py_CLEAR(self->results[i]);
    return 0;
}

static void
fc_dealloc(FastCall *self)
{
    PyObject_GC_UnTrack(self);
    if (self->release && self->fn) self->release(self->mem);
    fc_clear(self);
    PyMem_Free(self->in_bytes);
    PyMem_Free(self->arg);
    PyMem_Free(self->res);
    PyMem_Free(self->results);
    PyObject_GC_Del(self);
}

static PyObject *
fc_get_fallback(FastCall *self, void *closure)
{
    return Py_NewRef(self->fallback ? self->fallback : Py_None);
}

static PyMethodDef fc_methods[] = {
    {"set_res", (PyCFunction)fc_set_res, METH_VARARGS, "point output k at an array"},
    {NULL, NULL, 0, NULL}
};

static PyGetSetDef fc_getset[] = {
    {"fallback", (getter)fc_get_fallback, NULL, "the Python entry", NULL},
    {NULL}
};

static PyTypeObject FastCallType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "softgen.runtime._fastcall.FastCall",
    .tp_basicsize = sizeof(FastCall),
    .tp_dealloc = (destructor)fc_dealloc,
    .tp_vectorcall_offset = offsetof(FastCall, vectorcall),
    .tp_call = PyVectorcall_Call,
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_doc = "A bundle function's checked call in C (softgen.runtime.fastcall).",
    .tp_traverse = (traverseproc)fc_traverse,
    .tp_clear = (inquiry)fc_clear,
    .tp_methods = fc_methods,
    .tp_getset = fc_getset,
    .tp_new = fc_new,
};

static struct PyModuleDef fc_module = {
    PyModuleDef_HEAD_INIT, "_fastcall", NULL, -1, NULL
};

PyMODINIT_FUNC
PyInit__fastcall(void)
{
    PyObject *m;
    import_array();
    if (PyType_Ready(&FastCallType) < 0) return NULL;
    m = PyModule_Create(&fc_module);
    if (m == NULL) return NULL;
    Py_INCREF(&FastCallType);
    if (PyModule_AddObject(m, "FastCall", (PyObject *)&FastCallType) < 0) {
        Py_DECREF(&FastCallType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
"""

_MODULE: list = []      # [module or None] once tried


def module():
    """The compiled ``_fastcall`` extension (built on first use, cached), or None."""
    if not _MODULE:
        _MODULE.append(_load())
    return _MODULE[0]


def _load():
    if os.environ.get("SOFTGEN_FASTCALL", "1") == "0":
        return None
    try:
        where = _target()
        if where is None:
            return None
        lib, cc, include, np_include = where
        for attempt in range(2):
            if attempt or not lib.is_file():
                if not _build(lib, cc, include, np_include):
                    return None
            try:
                return _import(lib)
            except ImportError:         # a damaged cache entry: build it again, once
                continue
        return None
    except Exception:      # noqa: BLE001 - any failure: the Python entry stays
        return None


def _target() -> tuple[Path, str, str, str] | None:
    """Where the extension for this Python and NumPy is cached, and what builds it:
    (library, compiler, Python headers, NumPy headers); None without any of them."""
    import numpy as np

    from softgen.codegen.build import find_compiler
    from softgen.core.paths import cache_dir
    cc = find_compiler(None)
    include = sysconfig.get_paths().get("include")
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    if cc is None or not include or not (Path(include) / "Python.h").is_file():
        return None
    tag = hashlib.sha256("\0".join([SOURCE, sys.version, np.__version__, np.get_include(),
                                    str(cc)]).encode()).hexdigest()[:16]
    return cache_dir() / "fastcall" / f"_fastcall_{tag}{suffix}", cc, include, np.get_include()


def _build(lib: Path, cc: str, include: str, np_include: str) -> bool:
    """Compile :data:`SOURCE` into ``lib`` (atomically: concurrent builds are fine)."""
    from softgen.core import children
    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        src = Path(tmp) / "_fastcall.c"
        src.write_text(SOURCE)
        out = Path(tmp) / lib.name
        proc = children.run([cc, "-O2", "-fPIC", "-shared", "-I", include, "-I", np_include,
                             "-o", str(out), str(src)], timeout=120)
        if proc.returncode != 0:
            return False
        os.replace(out, lib)
    return True


def _import(lib: Path):
    spec = importlib.util.spec_from_file_location("_fastcall", lib)
    if spec is None or spec.loader is None:
        raise ImportError(f"{lib}: not loadable")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
