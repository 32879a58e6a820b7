"""``--root LINK`` and ``--tip LINK``: the serial chain of a URDF tree, for every verb
that takes a model (issue 24).

Without them a verb passes the model's name or path on as before; with them it loads
the chain (:func:`softgen.modelfile.load.load_model`, the same cut as a TOML model's
``[urdf]`` table) and hands the loaded model to the application layer. An unknown link,
a tip not below the root, or the flags on a TOML model are one ``softgen: error:`` line.
"""
from __future__ import annotations

from softgen.core.errors import SoftgenError


def add_chain_arguments(p) -> None:
    g = p.add_argument_group("chain of a URDF tree (a gripper off an arm, an arm off a "
                             "humanoid)")
    g.add_argument("--root", metavar="LINK", help="the fixed base link; links above it are "
                   "not modelled (default: the file's root link)")
    g.add_argument("--tip", metavar="LINK", help="the last link of the chain; moving joints "
                   "off the root->tip path (fingers, other limbs) are left out")


def has_chain(args) -> bool:
    return args.root is not None or args.tip is not None


def chain_model(args, ref, verb: str):
    """``ref`` (a model name or path) as the verb passes it on: unchanged without
    ``--root``/``--tip``, else the loaded chain.

    Either way the model's size is checked here, before the verb derives anything
    (:func:`softgen.modelfile.limits.check_expression_size`, one line naming
    ``SOFTGEN_MAX_EXPRESSION_SIZE``): every verb that takes a model gets the same check
    (issue 36: ``check``, ``export``, ``identify``, ``observer`` and ``estimate`` derived
    for minutes in silence)."""
    from softgen.modelfile.limits import check_expression_size
    from softgen.modelfile.load import load_model
    if not has_chain(args):
        if ref is not None:
            check_expression_size(load_model(ref))
        return ref
    if ref is None:
        raise SoftgenError(f"{verb}: --root/--tip choose a chain of a URDF MODEL; give one")
    model = load_model(ref, root=args.root, tip=args.tip)
    check_expression_size(model)
    return model


def single_model(args, models: list[str], verb: str) -> None:
    """``--root``/``--tip`` cut one file's chain: refuse them with several MODELs."""
    if has_chain(args) and len(models) != 1:
        raise SoftgenError(f"{verb}: --root/--tip choose the chain of one URDF MODEL; "
                           f"got {len(models)} models")
