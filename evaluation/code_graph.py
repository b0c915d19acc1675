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
from collections.abc import Iterable
from pathlib import Path

#: The package whose modules are followed (imports of other packages are left out: their versions are keyed apart).
PACKAGE = "snac_gym"


@functools.lru_cache(maxsize=None)
def _origin(name: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
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
