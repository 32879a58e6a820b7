"""How big a model's derived expressions will be, known before anything is derived.

A 60-link chain ran 20 minutes (110 MB of C, gcc at 2.9 GB) and a 40-segment planar
PCC model 15 minutes at 2.5 GB before being killed, printing nothing (issue 23).
:func:`expression_size` estimates, from the model file alone (links, segments,
quadrature points, uncertain parameters), the number of CasADi operations of the
functions ``softgen generate`` and ``softgen info`` derive for it;
:func:`check_expression_size` refuses a model past :data:`MAX_EXPRESSION_SIZE` with
one line naming the estimate, the limit and the environment variable that raises it
(``SOFTGEN_MAX_EXPRESSION_SIZE``). It takes microseconds: call it before deriving.

The estimate is a fit to measured derivations (``bundle_spec`` of the default bundle (affine: ``soft_pendulum``, 8 quadrature points),
the sum of ``n_instructions()`` of its functions, 2026-12-02):

==================  ===========  ==========  ============  ==========
model               DoF          uncertain   measured ops  estimate
==================  ===========  ==========  ============  ==========
planar, 4 links     4            12          5,246         5,760
planar, 8 links     8            24          20,251        23,040
planar, 12 links    12           36          47,963        51,840
planar, 16 links    16           48          92,219        92,160
spatial, 7 links    7            70          58,044        56,595
spatial, 12 links   12           120         164,045       166,320
pcc-planar, 4 seg.  4            16          31,905        32,000
pcc-3d, 4 seg.      12           16          118,519       118,272
affine, 1 seg., 8   2            4           20,329        20,160
==================  ===========  ==========  ============  ==========

Trees (issue 35) take the recursive route, the composite-rigid-body B and a symbolic LU
of B for the forward dynamics; measured on whole vendor trees (``bundle_spec``, the sum
of ``n_instructions()``, 2027-01):

==========================  ====  ====  ============  ==========
model                       nv    p     measured ops  estimate
==========================  ====  ====  ============  ==========
ANYmal C, fixed base        12    120   39,865        47,520
Baxter, fixed base          17    207   128,448       114,240
Talos (reduced), fixed      32    340   324,816       357,120
Solo 12, floating           18    130   40,719        29,210
ANYmal C, floating          18    130   49,682        29,210
simple humanoid, floating   35    300   168,254       167,825
Talos (reduced), floating   38    350   219,992       213,818
==========================  ====  ====  ============  ==========

so a fixed-base tree is estimated as 30 n (n + p) (it gets the Slotine–Li loop and the
nominal plant, as a chain), a floating base as 2.2 nv³ + 7 nv p (the LU of B and the
whole-body regressor; accurate for the large ones, which the limit is about).

Rigid chains grow as n (n + p) (n joints, p uncertain parameters: the matrix-free
route, docs/design.md); soft chains as s³ (dof + p) times the quadrature points (every
point's position depends on every earlier segment, and the inertia sums over them;
an 8-segment planar PCC model did not finish deriving in 150 s). The default limit,
250,000 operations, is about a minute of derivation and compilation: 26 planar or 14
spatial links, 6 planar PCC or 4 spatial PCC segments with the default parameters.
"""
from __future__ import annotations

import os

from softgen.core.errors import ModelError

#: Default largest estimated expression size (CasADi operations) a model may derive.
MAX_EXPRESSION_SIZE = 250_000

#: The environment variable that raises (or lowers) :data:`MAX_EXPRESSION_SIZE`.
ENV_VAR = "SOFTGEN_MAX_EXPRESSION_SIZE"

#: Operations per unit of the size measure, by model kind (fits of the table above).
_RIGID = {"planar": 90.0, "spatial": 105.0}
_SOFT = {"pcc-planar": 25.0, "pcc-3d": 66.0, "affine-planar": 420.0}
#: Fixed-base trees, n (n + p); floating bases, (nv³, nv p) (the trees' table above).
_TREE = 30.0
_FLOATING = (2.2, 7.0)


def expression_size(model) -> int:
    """Estimated CasADi operations of the functions derived for ``model`` (a rigid or
    soft model object of :mod:`softgen.modelfile`); see the module docstring."""
    p = len(model.uncertain)
    if model.kind == "cosserat":
        return cosserat_size(model)
    if hasattr(model, "segments"):
        s = len(model.segments)
        points = max(seg.quadrature_order for seg in model.segments)
        c = _SOFT.get(model.kind, max(_SOFT.values()))
        return int(c * s ** 3 * (model.dof + p) * points)
    n = len(model.links)
    if getattr(model, "floating", False):
        nv = model.nv
        return int(_FLOATING[0] * nv ** 3 + _FLOATING[1] * nv * p)
    if getattr(model, "is_tree", False):
        return int(_TREE * n * (n + p))
    c = _RIGID.get(model.kind, max(_RIGID.values()))
    return int(c * n * (n + p))


#: Operations per (node × coordinate of its rod), fit to measured Cosserat bundles
#: (2026-12-05, the default bundle with the tip-control loop: 3 segments of 3 strains,
#: 126k measured, 89k estimated; of 6 strains, 249k measured, 239k estimated).
_COSSERAT = 2400.0


def cosserat_size(model) -> int:
    """Cosserat chains (issue 33) grow linearly in nodes: each rod node costs about its
    rod's coordinates d times a constant (its S is 6 × d, Ṡ and the articulated solve
    add d²); the formed B, C, Y and statics Jacobian add the n × n matrices."""
    size = 0.0
    for b in model.bodies:
        d = getattr(b, "dof", 1)
        nodes = getattr(b, "quadrature", 0) + 1
        size += _COSSERAT * nodes * d * (1 + d / 12)
    return int(size + 50.0 * model.dof ** 2 * (1 + len(model.uncertain) / 10))


def expression_limit() -> int:
    """:data:`MAX_EXPRESSION_SIZE`, or ``$SOFTGEN_MAX_EXPRESSION_SIZE`` when set."""
    env = os.environ.get(ENV_VAR)
    if env is None or not env.strip():
        return MAX_EXPRESSION_SIZE
    try:
        value = int(float(env))
    except (ValueError, OverflowError):
        value = 0
    if value < 1:
        raise ModelError(f"{ENV_VAR}: expected a positive number of operations, got {env!r}")
    return value


def check_expression_size(model, limit: int | None = None) -> int:
    """The estimate of :func:`expression_size`, or one :class:`ModelError` line when it
    is over ``limit`` (default :func:`expression_limit`) naming the limit and
    ``SOFTGEN_MAX_EXPRESSION_SIZE``."""
    size = expression_size(model)
    limit = expression_limit() if limit is None else limit
    if size > limit:
        # A rigid chain or tree also has bodies (the shared recursion): name what the
        # user wrote, links for a rigid model, segments (rods) for a soft one.
        parts = (f"{len(model.bodies)} segments" if model.kind == "cosserat"
                 else f"{len(model.segments)} segments" if hasattr(model, "segments")
                 else f"{len(model.links)} links")
        where = model.path if getattr(model, "path", None) is not None else model.name
        raise ModelError(
            f"{where}: model too large to derive: {parts}, {model.dof} DoF and "
            f"{len(model.uncertain)} uncertain parameters give an estimated {size:,} "
            f"operations, over the limit of {limit:,} (about a minute of derivation; set "
            f"{ENV_VAR}={size} to derive it anyway, or make fewer parameters uncertain)")
    return size


# -- the other sizes a verb derives or allocates from (issue 36) -------------------------

class LimitError(ModelError):
    """An input whose size is over a documented limit (one line: the size, the limit, the
    environment variable that raises it)."""


class Limit:
    """A size a verb checks before it derives or allocates: a default and the environment
    variable that changes it (one home for each number; the message names both).

    Parameters
    ----------
    what
        What is counted, as the message says it ("rows of a measurement log").
    default
        The limit when the environment variable is not set.
    env
        ``SOFTGEN_MAX_...``.
    why
        What passing it would cost, for the message ("about a minute and 1 GB").
    """

    def __init__(self, what: str, default: int, env: str, why: str):
        self.what, self.default, self.env, self.why = what, default, env, why

    def value(self) -> int:
        """The limit: ``$env`` when set (a positive number), else the default."""
        text = os.environ.get(self.env)
        if text is None or not text.strip():
            return self.default
        try:
            value = int(float(text))
        except (ValueError, OverflowError):
            value = 0
        if value < 1:
            raise LimitError(f"{self.env}: expected a positive number of {self.what}, "
                             f"got {text!r}")
        return value

    def check(self, n: float, subject: str, qualifier: str = "") -> int:
        """``n`` when within the limit, else one :class:`LimitError` line that starts with
        ``subject`` (the option or file) and names the limit and the variable;
        ``qualifier`` precedes the number ("about ", "more than ")."""
        limit = self.value()
        if not n <= limit:                       # also NaN
            shown = f"{n:,.0f}" if abs(n) < 1e18 else f"{n:.3g}"
            raise LimitError(f"{subject}: {qualifier}{shown} {self.what}, over the limit of "
                             f"{limit:,} ({self.why}; set {self.env} to raise it)")
        return int(n)


#: Rows of a measurement log read by ``estimate`` and ``identify``, and of a trajectory
#: ``identify --excite`` writes. A 1e7-row log took 90 CPU-s and 6.8 GB in ``estimate``
#: with no output (issue 36): about 700 bytes and 9 µs per row through the estimator,
#: so a million rows is about 10 s and 700 MB (5,000 s of a 5 ms log).
LOG_ROWS = Limit("rows", 1_000_000, "SOFTGEN_MAX_LOG_ROWS",
                 "about 10 s and 700 MB per million rows")

#: Harmonics per joint of an excitation trajectory (``identify --excite --harmonics``):
#: the optimiser's variables grow as 2 × harmonics × joints and each iteration evaluates
#: the regressor on the whole grid; Swevers et al. use 5. 100,000 harmonics ran
#: 21.6 CPU-s before a traceback (issue 36).
HARMONICS = Limit("harmonics", 50, "SOFTGEN_MAX_HARMONICS",
                  "each adds 2 optimisation variables per joint")

#: States of a system ``softgen observer`` designs for. The existence conditions take
#: ranks of (L+1)p × (L+1)m block matrices for every L ≤ n, about n⁴: a 1,000-state
#: system ran 82 CPU-s without output (issue 36). Measured on random systems with no
#: observer (the search runs to L = n; 2026-12-04, load 8): 50 states 2.9 CPU-s, 100
#: states 45 CPU-s. A 7-joint arm with qbmove drives has 42.
OBSERVER_STATES = Limit("states", 50, "SOFTGEN_MAX_OBSERVER_STATES",
                        "the delay search grows as n^4: 50 states take a few CPU-s, 100 "
                        "about a minute")

