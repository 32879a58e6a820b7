"""softgen: symbolic models, regressors, generated C and closed loops for soft robots."""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("softgen")
except PackageNotFoundError:     # run from a checkout without installing
    __version__ = "0+unknown"
