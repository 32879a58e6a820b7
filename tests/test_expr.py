"""The safe law parser (softgen.modelfile.expr): allowed forms equal numpy, everything
else is one ModelError line naming the file and key, also on random junk."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softgen.core.errors import ModelError
from softgen.modelfile.expr import FUNCTIONS, MAX_EXPONENT, parse_law

WHERE = "models/x.toml: actuators[1].law"
NAMES = ("phi", "k", "a")

#: Allowed forms and their numpy equivalents (x = phi, k, a as numbers).
ALLOWED = [
    ("k*sinh(a*phi)", lambda phi, k, a: k * np.sinh(a * phi)),
    ("k*phi", lambda phi, k, a: k * phi),
    ("-k*phi + +a", lambda phi, k, a: -k * phi + a),
    ("(phi + 1)**2 - a**-1", lambda phi, k, a: (phi + 1) ** 2 - a ** -1.0),
    ("phi**3/3 - k/(a + 2)", lambda phi, k, a: phi ** 3 / 3 - k / (a + 2)),
    ("2**a", lambda phi, k, a: 2.0 ** a),
    ("-phi**2", lambda phi, k, a: -phi ** 2),
    ("sin(phi)*cos(a) + tan(k/10)", lambda phi, k, a: np.sin(phi) * np.cos(a) + np.tan(k / 10)),
    ("exp(phi) - log(k) + sqrt(a)", lambda phi, k, a: np.exp(phi) - np.log(k) + np.sqrt(a)),
    ("cosh(phi) + tanh(a*phi)", lambda phi, k, a: np.cosh(phi) + np.tanh(a * phi)),
    ("asinh(phi) + acosh(1 + a) + atanh(phi/2)",
     lambda phi, k, a: np.arcsinh(phi) + np.arccosh(1 + a) + np.arctanh(phi / 2)),
    ("atan(phi) + atan2(phi, -k)", lambda phi, k, a: np.arctan(phi) + np.arctan2(phi, -k)),
    ("abs(phi) + fmin(phi, k) - fmax(a, phi)",
     lambda phi, k, a: np.abs(phi) + np.minimum(phi, k) - np.maximum(a, phi)),
    ("pi*phi", lambda phi, k, a: math.pi * phi),
    ("1.5e-3 * phi + 7", lambda phi, k, a: 1.5e-3 * phi + 7),
    ("  k * ( phi\n + a )  ", lambda phi, k, a: k * (phi + a)),
]


@pytest.mark.parametrize("text,ref", ALLOWED, ids=[t for t, _ in ALLOWED])
def test_allowed_forms_equal_numpy(text, ref):
    law = parse_law(text, NAMES, WHERE)
    x = ca.SX.sym("x", 3)
    f = ca.Function("f", [x], [law({"phi": x[0], "k": x[1], "a": x[2]})])
    rng = np.random.default_rng(1)
    for _ in range(20):
        phi, k, a = rng.uniform(-1.5, 1.5), rng.uniform(0.1, 3), rng.uniform(0.1, 3)
        np.testing.assert_allclose(float(f([phi, k, a])), ref(phi, k, a), rtol=1e-13,
                                   atol=1e-13)


def test_numbers_and_symbols_mix():
    """Names may be given numbers or SX; the result is SX either way."""
    law = parse_law("k*sinh(a*phi)", NAMES, WHERE)
    assert float(ca.evalf(law({"phi": 0.3, "k": 2.0, "a": 1.5}))) == \
        pytest.approx(2.0 * math.sinh(0.45), rel=1e-15)
    assert law.used == {"phi", "k", "a"}


REJECTED = [
    ("q2*k", "unknown name 'q2' (expected one of phi, k, a)"),
    ("().__class__", "attribute access not allowed"),
    ("phi.real", "attribute access not allowed"),
    ("phi[0]", "subscripts not allowed"),
    ("lambda: 1", "lambdas not allowed"),
    ("'s'", "only numbers are allowed"),
    ("1 < phi", "comparisons not allowed"),
    ("phi and k", "boolean operators not allowed"),
    ("phi if k else a", "conditionals not allowed"),
    ("[phi]", "lists not allowed"),
    ("(phi, k)", "tuples not allowed"),
    ("phi ** 1000", f"exponent 1000 too large (at most {MAX_EXPONENT}"),
    ("phi ** -1e5", "exponent -100000 too large"),
    ("foo(phi)", "unknown function 'foo'"),
    ("__import__('os')", "unknown function '__import__'"),
    ("sin", "'sin' is a function"),
    ("sin(phi, k)", "sin() takes 1 argument(s), got 2"),
    ("atan2(phi)", "atan2() takes 2 argument(s), got 1"),
    ("sin(x=phi)", "keyword arguments are not allowed"),
    ("phi % 2", "operator Mod is not allowed"),
    ("phi // 2", "operator FloorDiv is not allowed"),
    ("phi @ k", "operator MatMult is not allowed"),
    ("~phi", "operator Invert is not allowed"),
    ("not phi", "operator Not is not allowed"),
    ("1e400", "is not finite"),
    ("9" * 400, "is not finite"),
    ("1j * phi", "only numbers are allowed"),
    ("True * phi", "only numbers are allowed"),
    ("(((", "not an expression"),
    ("", "expected an expression"),
    ("phi; k", "not an expression"),
    ("x := 1", "not an expression"),
    ("(x := phi)", "assignments not allowed"),
    ("f'{phi}'", "f-strings not allowed"),
    ("[p for p in k]", "comprehensions not allowed"),
    ("sin(*phi)", "starred arguments not allowed"),
    ("phi.__class__.__mro__", "attribute access not allowed"),
    ("(phi)(k)", "unknown function"),
    ("+" * 2000 + "phi", "characters (at most"),
    ("phi\x00", "not an expression"),
]


@pytest.mark.parametrize("text,msg", REJECTED, ids=[repr(t[:20]) for t, _ in REJECTED])
def test_rejected_forms_are_one_line_naming_file_and_key(text, msg):
    with pytest.raises(ModelError) as err:
        parse_law(text, NAMES, WHERE)
    line = str(err.value)
    assert line.startswith(WHERE + ": ")
    assert msg in line
    assert "\n" not in line


def test_non_string_law():
    with pytest.raises(ModelError, match="expected a string"):
        parse_law(3.0, NAMES, WHERE)


def test_deep_nesting_is_one_line():
    with pytest.raises(ModelError) as err:
        parse_law("(" * 900 + "phi" + ")" * 900, NAMES, WHERE)
    assert str(err.value).startswith(WHERE) and "\n" not in str(err.value)


_ALPHABET = list("phikas0123456789.+-*/()[]{},;:=<>!%&|^~@'\"\\ _eE\t") + \
    ["sin", "sinh", "**", "lambda", "import", "__", "pi", "1e999", "phi", "k", "a", " if ",
     "atan2(", "fmin(", "x."]


@pytest.mark.parametrize("seed", range(4))
def test_fuzzed_junk_never_escapes_as_another_error(seed):
    """Random strings: each either parses (and then evaluates to an SX) or raises the
    one-line ModelError; no other exception type gets out."""
    rng = np.random.default_rng(seed)
    phi = ca.SX.sym("phi")
    parsed = 0
    for _ in range(600):
        n = int(rng.integers(1, 25))
        text = "".join(_ALPHABET[int(i)] for i in rng.integers(0, len(_ALPHABET), n))
        try:
            law = parse_law(text, NAMES, WHERE)
        except ModelError as exc:
            assert str(exc).startswith(WHERE + ": ") and "\n" not in str(exc)
            continue
        parsed += 1
        assert isinstance(law({"phi": phi, "k": 2.0, "a": 0.5}), ca.SX)
    assert parsed < 600


def _random_tree(rng, depth: int) -> str:
    """A random allowed expression over phi, k, a (numbers kept in safe domains by
    wrapping the arguments of log/sqrt/acosh/atanh)."""
    if depth == 0 or rng.random() < 0.25:
        return str(rng.choice(["phi", "k", "a", "pi", f"{rng.uniform(0.1, 3):.3f}"]))
    r = rng.random()
    x, y = _random_tree(rng, depth - 1), _random_tree(rng, depth - 1)
    if r < 0.45:
        op = str(rng.choice(["+", "-", "*"]))
        return f"({x} {op} {y})"
    if r < 0.55:
        return f"({x} / (2 + abs({y})))"
    if r < 0.6:
        return f"-({x})"
    if r < 0.65:
        return f"({x})**2"
    fn = str(rng.choice(sorted(FUNCTIONS)))
    safe = {"log": "(1 + abs({}))", "sqrt": "abs({})", "acosh": "(1 + abs({}))",
            "atanh": "tanh({})/2", "exp": "sin({})", "sinh": "sin({})", "cosh": "sin({})",
            "tan": "atan({})/2"}
    arg = safe.get(fn, "{}").format(x)
    if FUNCTIONS[fn][0] == 2:
        return f"{fn}({arg}, {y})"
    return f"{fn}({arg})"


_NUMPY = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "exp": np.exp, "log": np.log,
          "sqrt": np.sqrt, "sinh": np.sinh, "cosh": np.cosh, "tanh": np.tanh,
          "asinh": np.arcsinh, "acosh": np.arccosh, "atanh": np.arctanh, "atan": np.arctan,
          "atan2": np.arctan2, "abs": np.abs, "fmin": np.minimum, "fmax": np.maximum,
          "pi": math.pi}


@pytest.mark.parametrize("seed", range(3))
def test_random_allowed_trees_equal_numpy(seed):
    """Random expressions of allowed forms: CasADi's value equals numpy's (the test
    evaluates the same text with numpy functions, its own trusted input)."""
    rng = np.random.default_rng(100 + seed)
    x = ca.SX.sym("x", 3)
    for _ in range(60):
        text = _random_tree(rng, 4)
        law = parse_law(text, NAMES, WHERE)
        f = ca.Function("f", [x], [law({"phi": x[0], "k": x[1], "a": x[2]})])
        v = rng.uniform(-1, 1, 3)
        ref = eval(text, {"__builtins__": {}}, {**_NUMPY, "phi": v[0], "k": v[1], "a": v[2]})
        np.testing.assert_allclose(float(f(v)), ref, rtol=1e-12, atol=1e-12, err_msg=text)
