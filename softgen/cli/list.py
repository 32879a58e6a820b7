"""``softgen list``: models and experiments"""
from __future__ import annotations

HELP = "models and experiments"


def add_arguments(p) -> None:
    pass


def run(args) -> int:
    from softgen.experiments.registry import experiment_ids, get
    from softgen.modelfile.load import list_models, load_model
    models = [load_model(name) for name in list_models()]
    w = max((len(m.name) for m in models), default=0)
    k = max((len(m.kind) for m in models), default=0)
    print("models:")
    for m in models:
        print(f"  {m.name:<{w}}  {m.kind:<{k}}  {m.dof:>2} dof  {m.description}")
    ids = experiment_ids()
    w = max((len(i) for i in ids), default=0)
    print("experiments:")
    for exp_id in ids:
        e = get(exp_id)
        print(f"  {exp_id:<{w}}  {e.title}  [{e.section}]")
    return 0
