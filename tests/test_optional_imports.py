"""The modules that import an optional extra (JAX, Dask) at their top are the few
:data:`test_plain_install.NEEDS_AN_EXTRA` names, found here by reading the source, in a second.

The ground truth is ``make check-plain-install`` (tests/test_plain_install.py), which imports every
module in an environment without the extras; it builds that environment, so ``make test`` leaves it
to CI. This check runs in the main suite so that a new module-level ``import jax`` (or an import of
a module that has one) is caught by ``make test`` too: each module's top-level imports (outside
functions and ``if TYPE_CHECKING:``), followed through pfx's own modules.
"""

from __future__ import annotations

import ast
from pathlib import Path

from test_plain_install import NEEDS_AN_EXTRA

PACKAGE = Path(__file__).resolve().parents[1] / "pfx"
EXTRAS = {"jax": "jax", "jaxlib": "jax", "dask": "dask", "distributed": "dask"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _top_level_imports(tree: ast.Module, modules: set[str]) -> set[str]:
    """The modules a module imports when it is imported: its top-level statements, into
    ``if``/``try`` blocks but not functions, classes or ``if TYPE_CHECKING:``."""
    imported: set[str] = set()

    def visit(statements) -> None:
        for statement in statements:
            if isinstance(statement, ast.Import):
                imported.update(alias.name for alias in statement.names)
            elif isinstance(statement, ast.ImportFrom) and statement.module and not statement.level:
                imported.add(statement.module)
                imported.update(f"{statement.module}.{alias.name}" for alias in statement.names
                                if f"{statement.module}.{alias.name}" in modules)
            elif isinstance(statement, ast.If):
                if "TYPE_CHECKING" not in ast.unparse(statement.test):
                    visit(statement.body)
                visit(statement.orelse)
            elif isinstance(statement, ast.Try):
                for block in (statement.body, statement.orelse, statement.finalbody):
                    visit(block)

    visit(tree.body)
    return imported


def test_the_modules_that_need_an_extra_are_the_listed_ones():
    sources = {_module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}
    imports = {name: _top_level_imports(ast.parse(path.read_text()), set(sources)) for name, path in sources.items()}
    needs = {name: EXTRAS[extra] for name, imported in imports.items()
             for extra in EXTRAS if any(module == extra or module.startswith(extra + ".") for module in imported)}
    changed = True
    while changed:                         # through pfx's own modules: importing one that needs an extra
        changed = False
        for name, imported in imports.items():
            for module in imported:
                if name not in needs and module in needs:
                    needs[name], changed = needs[module], True
    assert needs == NEEDS_AN_EXTRA, (
        "modules that import an optional extra when imported changed: import JAX or Dask inside the function "
        f"that asks for it, or list a backend module in tests/test_plain_install.py: {needs}")
