"""Imports flow one way (docs/architecture.md): no cycles, no upward imports, no reaching into privates.

Every import statement of the library counts, at module level and inside functions alike (a
function-level import hides a cycle from Python, not from the design).
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("gsslam",)
# The top-level folder factors/ is the package gsslam.factors (setuptools package-dir mapping; in a
# checkout gsslam/factors is a link to it). No top-level `factors` package exists.
FACTORS = REPO / "factors"


def _module_name(path: Path) -> str:
    if path.is_relative_to(FACTORS):
        path = REPO / "gsslam" / path.relative_to(REPO)
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    files = [p for p in (REPO / "gsslam").rglob("*.py") if not p.is_relative_to(REPO / "gsslam" / "factors")]
    return {_module_name(p): p for p in sorted(files + list(FACTORS.rglob("*.py")))}


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES.get(name, Path()).name == "__init__.py"


@cache
def _imports(name: str) -> list[tuple[str, list[str], int]]:
    """``(imported module, names taken from it, line)`` for every import statement of module ``name``."""
    tree = ast.parse(MODULES[name].read_text(), str(MODULES[name]))
    package = name if _is_package(name) else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            out.append((base, [a.name for a in node.names], node.lineno))
    return out


@cache
def _edges() -> dict[str, set[str]]:
    """Module -> library modules it imports (``from pkg import mod`` counts as importing ``pkg.mod``)."""
    edges: dict[str, set[str]] = {m: set() for m in MODULES}
    for m in MODULES:
        for target, names, _ in _imports(m):
            if target.split(".")[0] not in PACKAGES:
                continue
            subs = [f"{target}.{n}" for n in names if f"{target}.{n}" in MODULES]
            for t in subs or [target]:
                if t in MODULES and t != m:
                    edges[m].add(t)
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_walk_sees_the_library():
    assert {"gsslam.slam.pipeline", "gsslam.run.sequence", "gsslam.mapping.state", "gsslam.factors"} <= set(
        MODULES
    )
    edges = _edges()
    assert "gsslam.slam.pipeline" in edges["gsslam.run.sequence"]
    assert "gsslam.mapping.window" in edges["gsslam.mapping.mapper"]  # `from gsslam.mapping import ...`


def test_no_import_cycles():
    assert _cycles(_edges()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if parts[0] == "gsslam" and len(parts) > 1 else parts[0]


# the command line: cli.py (the app, run_cli) + the commands it registers from cli_batch.py, cli_bench.py + its progress bar (cli_progress.py)
CLI = ("cli", "cli_batch", "cli_bench", "cli_progress")
# layer -> the gsslam layers it must never import
FORBIDDEN = {
    **{low: {"slam", "run", *CLI, "bench", "__main__"}
       for low in ("frontend", "graph", "mapping", "loop", "datasets")},
    "slam": {"run", *CLI, "bench", "__main__"},
    "run": {*CLI, "bench", "__main__"},
    **{cli: {"slam", "frontend", "graph", "mapping", "loop", "datasets"} for cli in CLI},  # through run/
    **{base: {"slam", "run", *CLI, "bench", "frontend", "graph", "mapping", "loop", "datasets", "viz"}
       for base in ("config", "config_schema", "config_ranges", "types", "compact", "geometry", "imaging", "errors")},
}  # fmt: skip
PURE = {
    "eval": {"eval", "types", "geometry", "imaging", "errors"},
    "io": {"io", "types", "geometry", "errors"},
}


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith("gsslam.")))
def test_imports_flow_one_way(module):
    layer = _layer(module)
    bad = []
    for target in _edges()[module]:
        t = _layer(target)
        if t in FORBIDDEN.get(layer, ()) or (layer in PURE and t not in PURE[layer]):
            bad.append(target)
    assert not bad, f"{module} imports {sorted(bad)} (docs/architecture.md, 'Dependencies between packages')"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _layer(m) == "factors"))
def test_factors_need_only_gtsam_and_numpy(module):
    targets = {t for t, _, _ in _imports(module)}
    bad = {
        t
        for t in targets
        if t.split(".")[0] == "torch" or (t.startswith("gsslam") and _layer(t) != "factors")
    }
    assert not bad, f"{module} imports {sorted(bad)}"
    assert not any(t.split(".")[0] == "factors" for t in targets), (
        f"{module}: import gsslam.factors, not factors"
    )


def test_no_top_level_factors_package_is_installed():
    import tomllib

    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert setuptools["package-dir"] == {"gsslam.factors": "factors"}
    assert setuptools["packages"]["find"]["include"] == ["gsslam*"]
    import gsslam.factors

    assert Path(gsslam.factors.__file__).resolve().parent == FACTORS


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_reaches_into_another_modules_privates(module):
    bad = [
        f"line {line}: from {target} import {n}"
        for target, names, line in _imports(module)
        if target.split(".")[0] in PACKAGES and target != module
        for n in names
        if n.startswith("_") and not n.startswith("__")
    ]
    for node in ast.walk(ast.parse(MODULES[module].read_text())):
        # obj._name on anything but self / cls: another object's private state
        if (
            isinstance(node, ast.Attribute)
            and node.attr.startswith("_")
            and not node.attr.startswith("__")
            and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
        ):
            bad.append(f"line {node.lineno}: {ast.unparse(node)}")
    assert not bad, f"{module}: " + "; ".join(bad)


def test_dataset_registry_imports_loaders_lazily_and_knows_them_all():
    import importlib

    from gsslam.datasets import available_datasets
    from gsslam.datasets.base import BUILTIN_LOADERS

    assert set(available_datasets()) >= {"tum", "euroc", "kitti", "7scenes", "images", "synthetic"}
    base_imports = {t for t, _, _ in _imports("gsslam.datasets.base")}
    assert (
        not {f"gsslam.datasets.{m}" for m in ("tum", "euroc", "kitti", "sevenscenes", "images")}
        & base_imports
    )
    for name, target in BUILTIN_LOADERS.items():
        module, _, cls = target.partition(":")
        assert isinstance(getattr(importlib.import_module(module), cls), type), name
