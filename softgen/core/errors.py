"""Project exceptions.

Each subclasses a built-in so that callers may catch the generic kind
(python-control ``exception.py`` convention, docs/design.md section 3 item 7).
"""


class SoftgenError(Exception):
    """Base of every error softgen raises on purpose."""


class ModelError(SoftgenError, ValueError):
    """A model file or model description is invalid (names the file and key)."""


class ShapeError(SoftgenError, ValueError):
    """An array passed to a generated function has the wrong shape."""


class BuildError(SoftgenError, RuntimeError):
    """The C compiler failed or is missing; carries the compiler's stderr."""

    def __init__(self, message: str, stderr: str = ""):
        super().__init__(message if not stderr else f"{message}\n{stderr}")
        self.stderr = stderr


class BundleError(SoftgenError, RuntimeError):
    """A generated bundle is missing, stale or inconsistent with its manifest."""


class ExperimentError(SoftgenError, ValueError):
    """Unknown experiment id or an experiment configuration that does not check."""


class NonFiniteError(SoftgenError, ArithmeticError):
    """A computation produced NaN or infinity; names the first signal and time.

    Not bad input but a failed result: the command line exits with status 1.
    """

    exit_status = 1


class Interrupted(SoftgenError, RuntimeError):
    """A run stopped by SIGINT or SIGTERM after saving what had finished (status 130)."""

    exit_status = 130


class ImplausibleError(SoftgenError):
    """A result that ran but fails its plausibility check, refused on request
    (``estimate --strict``): exit status 3."""

    exit_status = 3
