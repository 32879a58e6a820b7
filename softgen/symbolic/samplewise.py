"""A CasADi function over many samples (columns) in chunks of one mapped function.

``f.map(K)`` of a K-sample trace costs more to build than to call at K of 10⁴-10⁵ (its
construction grows faster than K: 36 ms at K = 40,000 against 0.75 ms at 1,000 for the
qbmove spring torques, whose 40,000 evaluations take 37 ms). :func:`samplewise` evaluates
the same columns through one map of ``chunk`` samples (and one for the remainder): each
sample's value is the same double-precision evaluation, so the result is identical to the
single map's; only the building is cheaper.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

#: Samples per mapped call (building a map of 2048 costs ~1 ms).
CHUNK = 2048


def samplewise(f: ca.Function, *args, chunk: int = CHUNK) -> list[np.ndarray]:
    """``f`` at every column of ``args`` (each (size of that input, K)): its outputs as
    arrays (size of that output, K), what ``f.map(K)(*args)`` returns, built in chunks."""
    cols = [np.asarray(a, dtype=float) for a in args]
    cols = [a.reshape(1, -1) if a.ndim == 1 else a for a in cols]
    K = cols[0].shape[1]
    if any(a.shape[1] != K for a in cols):
        raise ValueError(f"samplewise {f.name()}: inputs with {[a.shape[1] for a in cols]} "
                         "samples (columns), expected one count")
    outs: list[list[np.ndarray]] = [[] for _ in range(f.n_out())]
    maps: dict[int, ca.Function] = {}
    for k0 in range(0, K, chunk):
        k1 = min(K, k0 + chunk)
        F = maps.get(k1 - k0)
        if F is None:
            F = maps[k1 - k0] = f.map(k1 - k0)
        for o, v in zip(outs, F.call([a[:, k0:k1] for a in cols])):
            o.append(np.array(v))
    return [np.hstack(o) if o else np.zeros((f.size1_out(i), 0)) for i, o in enumerate(outs)]
