"""``--root LINK``, ``--tip LINK`` and ``--floating``: the part of a URDF tree and its
base, for every verb that takes a model (issues 24, 35).

Without them a verb passes the model's name or path on as before (a URDF loads whole,
as a tree); with them it loads the model (:func:`softgen.modelfile.load.load_model`, the
same as a TOML model's ``[urdf]`` table) and hands the loaded model to the application
layer: ``--tip`` cuts the serial chain from ``--root`` (default: the file's root link),
``--root`` alone the tree below it, ``--floating`` puts the model on a floating base (a
free flyer: q = [base position, quaternion x y z w, joints], v = [base linear, angular
velocity in the base frame, joint rates], as Pinocchio's). An unknown link, a tip not
below the root, root/tip on a TOML model, or ``--floating`` on a verb that works on
fixed bases only are one ``softgen: error:`` line.
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
    g.add_argument("--floating", action="store_true", help="a floating base: the root link "
                   "(and what is fixed to it) is a free body, q = [position, quaternion x y z "
                   "w, joints], v = [base linear, angular velocity (base frame), joint rates]")


#: Verbs that take a floating base (the others work on fixed-base models).
FLOATING_VERBS = ("generate", "info", "export", "identify", "bench")


def has_chain(args) -> bool:
    return args.root is not None or args.tip is not None or getattr(args, "floating", False)


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
            model = load_model(ref)
            check_expression_size(model)
            if getattr(model, "floating", False) and verb not in FLOATING_VERBS:
                # floating = true in the file: the same rule as --floating (issue 36:
                # observer --model of such a file ended in a CasADi dimension traceback).
                raise SoftgenError(f"{verb}: {ref}: a floating base (floating = true); "
                                   f"{verb} works on fixed-base models; a floating base is "
                                   f"for {', '.join(FLOATING_VERBS)}")
        return ref
    floating = getattr(args, "floating", False)
    if floating and verb not in FLOATING_VERBS:
        raise SoftgenError(f"{verb}: --floating: {verb} works on fixed-base models; a "
                           f"floating base is for {', '.join(FLOATING_VERBS)}")
    if ref is None:
        raise SoftgenError(f"{verb}: --root/--tip/--floating choose a part of a URDF MODEL "
                           "or its base; give one")
    model = load_model(ref, root=args.root, tip=args.tip, floating=floating)
    check_expression_size(model)
    return model


def single_model(args, models: list[str], verb: str) -> None:
    """``--root``/``--tip`` cut one file's chain: refuse them with several MODELs."""
    if has_chain(args) and len(models) != 1:
        raise SoftgenError(f"{verb}: --root/--tip/--floating choose the part and base of one "
                           f"MODEL; got {len(models)} models")
