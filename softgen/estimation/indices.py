"""Moved to :mod:`softgen.studies.indices` (study code: metric records and a figure).

TEMPORARY re-export, and a layering exception (estimation may not import studies): the
estimation experiments (ch6/ch7, ``estimation_common``; another engineer's files) still
import from here. Delete this module once they import ``softgen.studies.indices``.
"""
from softgen.studies.indices import (error_records, estimation_figure,  # noqa: F401
                                     excitation_records, mse, msrep, noise_records,
                                     phase_records, update_fraction_records, window_mask)
