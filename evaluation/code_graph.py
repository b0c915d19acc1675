"""The code a cached value depends on, read off the import graph: a cache's key is derived from the modules that
compute its values, not from a list kept by hand (which had left out the robots' DH tables and velocity limits).

:func:`module_closure` follows every ``import``/``from ... import`` of the package's own modules (at module level
and inside functions alike) from the given roots, statically, by parsing the sources; :func:`sources_fingerprint`
is the SHA-256 of their text. A name imported from a module (``from snac_gym.model.kinematics import Kinematics``)
counts
as that module; a package's ``__init__`` counts only where it is imported as such. Code reached by name at run time
(a policy made by its registered name) is not in the graph: its module is given as a root
(:func:`snac_gym.policies.registry.policy_factory`).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import sys
from collections.abc import Iterable
from importlib.machinery import ModuleSpec
from pathlib import Path

#: The package whose modules are followed (imports of other packages are left out: their versions are keyed apart).
PACKAGE = "snac_gym"


@functools.lru_cache(maxsize=None)
def _spec(name: str) -> ModuleSpec | None:
    """The spec of module ``name``, found without running a module that is not a package.

    ``importlib.util.find_spec("a.b.C")`` imports ``a.b`` to look for ``C`` in it, and an import names attributes as
    often as modules (``from snac_gym.physics.mujoco import MujocoArms``): the key of a cache then imported MuJoCo, in
    every evaluator worker (0.5 s of a process). Here a dotted name is looked up by the import system's own finders in
    the folders of its parent's spec; a parent that is a plain module has no submodules, and nothing is imported."""
    module = sys.modules.get(name)
    if module is not None:
        return module.__spec__
    parent, _, _ = name.rpartition(".")
    if not parent:
        try:
            return importlib.util.find_spec(name)
        except (ImportError, ValueError):
            return None
    parent_spec = _spec(parent)
    if parent_spec is None or parent_spec.submodule_search_locations is None:
        return None  # a module's attribute, or under no package
    for finder in sys.meta_path:  # the finders an import of ``name`` asks, in their order, with the parent's path
        find = getattr(finder, "find_spec", None)
        spec = find(name, parent_spec.submodule_search_locations) if find is not None else None
        if spec is not None:
            return spec
    return None


@functools.lru_cache(maxsize=None)
def _origin(name: str) -> Path | None:
    spec = _spec(name)
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        return None
    return Path(spec.origin)


def _resolve(name: str) -> str | None:
    """The longest prefix of ``name`` that is a module of the package (``a.b.C`` → ``a.b``)."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if _origin(candidate) is not None:
            return candidate
        parts.pop()
    return None


#: The fields of a node that hold statements (a block's, an ``except``'s, a ``case``'s).
_BLOCKS = ("body", "orelse", "finalbody", "handlers", "cases")


def _statements(tree: ast.Module) -> list[ast.AST]:
    """Every statement of ``tree``, in every block at any depth (and the ``except`` and ``case`` clauses that hold
    blocks). An import is a statement, so this finds every one that :func:`ast.walk` finds without visiting the
    expressions, most of a module's nodes (the reference cache's key, made in every evaluator worker: 0.49 → 0.28 s a
    process). tests/evaluation/test_cache_entry.py checks that both walks find the same imports in every source file."""
    found: list[ast.AST] = []
    pending: list[ast.AST] = list(tree.body)
    while pending:
        node = pending.pop()
        found.append(node)
        for field in _BLOCKS:
            pending.extend(getattr(node, field, ()))
    return found


@functools.lru_cache(maxsize=None)
def imported_modules(name: str) -> frozenset[str]:
    """The package's modules that module ``name`` imports, anywhere in its source."""
    origin = _origin(name)
    if origin is None:
        return frozenset()
    is_package = origin.name == "__init__.py"
    found: set[str] = set()
    for node in _statements(ast.parse(origin.read_text(), str(origin))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the module's own package
                anchor = name.split(".") if is_package else name.split(".")[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base]) if base else ".".join(anchor)
            targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
        for target in targets:
            if target == PACKAGE or target.startswith(PACKAGE + "."):
                module = _resolve(target)
                if module is not None and module != name:
                    found.add(module)
    return frozenset(found)


def module_closure(roots: Iterable[str]) -> tuple[str, ...]:
    """Every module of the package reachable from ``roots`` by imports, the roots included, sorted."""
    seen: set[str] = set()
    pending = [root for root in roots]
    while pending:
        module = pending.pop()
        if module in seen or _origin(module) is None:
            continue
        seen.add(module)
        pending.extend(imported_modules(module) - seen)
    return tuple(sorted(seen))


def sources_fingerprint(modules: Iterable[str]) -> str:
    """SHA-256 of each module's name and source text."""
    digest = hashlib.sha256()
    for module in sorted(modules):
        origin = _origin(module)
        digest.update(module.encode())
        digest.update(origin.read_bytes() if origin is not None else b"missing")
    return digest.hexdigest()


__all__ = ["imported_modules", "module_closure", "sources_fingerprint"]
