"""Typed discrete-time blocks and closed-loop diagrams (docs/design.md section 1).

``Block``: a step ``x_next, y = step(x, u, p)`` with a sample time and named
layouts. ``ClosedLoop``: blocks wired by signal name, checked, generated as one
N-step function. The driver that runs a diagram is :func:`softgen.runtime.simulate`.
"""
from softgen.blocks.block import Block
from softgen.blocks.diagram import ClosedLoop
from softgen.blocks.layout import Layout, Signal

__all__ = ["Block", "ClosedLoop", "Layout", "Signal"]
