"""Bundles: what a model's generated code contains (:mod:`softgen.bundles.bundle`).

The builder modules register their capabilities on import, and the registry keeps them
in registration order, which is the order of a bundle's functions and of its manifest's
``capabilities_refused``. They are imported here, in one fixed order, because any import
of a ``softgen.bundles`` submodule runs this file first: the order (and so the bytes of
``generated/``) cannot depend on which module a process happened to import first. It
did: a process that imported ``softgen.bundles.rigid`` before ``bundle`` wrote manifests
whose refused capabilities came in another order (tests/test_codegen.py after
tests/test_compose.py).
"""
import softgen.bundles.cosserat  # noqa: F401
import softgen.bundles.floating  # noqa: F401
import softgen.bundles.rigid  # noqa: F401
import softgen.bundles.soft  # noqa: F401
import softgen.bundles.spring_pair  # noqa: F401
