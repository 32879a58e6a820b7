"""``generate --all`` says how far it is and how long is left (issue 32)."""
from __future__ import annotations

import re

from softgen.bundles.bundle import GENERATED_DIR
from softgen.cli.generate import Progress, _shipped_size


def test_progress_counts_and_weights_the_time_left_by_the_shipped_c(monkeypatch):
    names = ["pcc_3d_4seg", "planar_2link", "no_such_shipped_model"]
    clock = iter([0.0, 10.0, 12.0, 15.0])
    monkeypatch.setattr("softgen.cli.generate.time.perf_counter", lambda: next(clock))
    p = Progress(names, GENERATED_DIR)
    size = {n: _shipped_size(n, GENERATED_DIR) for n in names}
    assert size["pcc_3d_4seg"] > size["planar_2link"] > 0 and size["no_such_shipped_model"] == 0
    first = p.line("pcc_3d_4seg", "a generated")
    assert first.startswith("[1/3] a generated (10 s elapsed, about ")
    left = float(re.search(r"about (\d+) s left", first).group(1))
    # The largest bundle took 10 s; what is left is in proportion to the C still to write
    # (the model without shipped C weighs as the smallest that has).
    want = 10.0 * (2 * size["planar_2link"]) / size["pcc_3d_4seg"]
    assert abs(left - want) <= 0.5
    assert p.line("planar_2link", "b").startswith("[2/3] b (12 s elapsed, about ")
    assert p.line("no_such_shipped_model", "c") == "[3/3] c (15 s elapsed)"
