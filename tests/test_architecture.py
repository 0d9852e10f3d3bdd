"""The house rules of the package, read from its source: imports run one way down the
pipeline (function-local imports included), the simulator never reaches into the
diagnosis, the independent generator imports nothing of ``sdit_path``, no module takes
another's private names, and no import cycle exists between modules."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "sdit_path"

#: the layers, bottom first: a module may import its own layer and the layers below it.
#: ``""`` is the package root (``__version__``).
LAYERS: tuple[frozenset[str], ...] = (
    frozenset({"", "errors", "arrays", "fixed_point", "heap", "parallel", "output",
               "program_marks"}),
    frozenset({"config"}),
    frozenset({"geometry"}),
    frozenset({"machine"}),
    frozenset({"errormodel"}),
    frozenset({"interference"}),
    frozenset({"timing"}),
    frozenset({"nc", "postprocessors"}),
    frozenset({"plan"}),
    frozenset({"reading"}),
    frozenset({"sim"}),
    frozenset({"identify"}),
    frozenset({"diagnose"}),
    frozenset({"analyse"}),
    frozenset({"replan"}),
    frozenset({"reports"}),
    frozenset({"cli", "__main__"}),
)
LEVEL = {name: k for k, layer in enumerate(LAYERS) for name in layer}


def _module_name(path: Path, root: Path, top: str) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([top, *parts])


def _sources() -> dict[str, Path]:
    out = {_module_name(p, PACKAGE, "sdit_path"): p for p in PACKAGE.rglob("*.py")
           if not {"postprocessors", "samples", "templates"} & set(p.relative_to(PACKAGE).parts)}
    out.update({_module_name(p, ROOT / "postprocessors", "sdit_path.postprocessors"): p
                for p in (ROOT / "postprocessors").rglob("*.py")})
    return out


def _imports(name: str, path: Path) -> list[tuple[str, tuple[str, ...], int]]:
    """(absolute module, imported names, line) of every import of ``sdit_path``, at any
    depth of the module (function-local ones included)."""
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == "sdit_path":
                out.append((target, tuple(a.name for a in node.names), node.lineno))
        elif isinstance(node, ast.Import):
            out += [(a.name, (), node.lineno) for a in node.names
                    if a.name.split(".")[0] == "sdit_path"]
    return out


def _part(module: str) -> str:
    """The layer name of a module: its first package below ``sdit_path``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


SOURCES = _sources()
IMPORTS = {name: _imports(name, path) for name, path in SOURCES.items()}


def _resolve(target: str, names: tuple[str, ...]) -> list[str]:
    """The modules an import reaches: ``from pkg import module`` reaches the module."""
    hits = [f"{target}.{n}" for n in names if f"{target}.{n}" in SOURCES]
    return hits or [target]


def test_every_package_has_a_layer():
    missing = sorted({_part(m) for m in SOURCES} - set(LEVEL))
    assert not missing, f"give these a layer in LAYERS: {missing}"


def test_imports_run_down_the_layers():
    upward = []
    for name, imports in IMPORTS.items():
        here = LEVEL[_part(name)]
        for target, names, line in imports:
            for mod in _resolve(target, names):
                if LEVEL.get(_part(mod), -1) > here:
                    upward.append(f"{SOURCES[name].relative_to(ROOT)}:{line} imports {mod}")
    assert not upward, "imports that run up the pipeline:\n" + "\n".join(upward)


def test_the_simulator_never_imports_the_diagnosis():
    bad = [f"{name} imports {target}" for name, imports in IMPORTS.items()
           if _part(name) == "sim" for target, _, _ in imports
           if _part(target) == "diagnose"]
    assert not bad


def test_no_module_imports_another_ones_private_names():
    bad = []
    for name, imports in IMPORTS.items():
        for target, names, line in imports:
            private = [n for n in names if n.startswith("_") and not n.startswith("__")]
            if private and target != name:
                bad.append(f"{SOURCES[name].relative_to(ROOT)}:{line} takes {', '.join(private)} "
                           f"from {target}")
    assert not bad, "\n".join(bad)


def test_no_import_cycle_between_modules():
    graph = defaultdict(set)
    for name, imports in IMPORTS.items():
        for target, names, _ in imports:
            for mod in _resolve(target, names):
                if mod in SOURCES and mod != name and not name.startswith(mod + "."):
                    graph[name].add(mod)
    # a package's __init__ re-exporting its modules is not a cycle of its modules
    seen, stack, cycles = set(), [], []

    def visit(m):
        if m in stack:
            cycles.append(stack[stack.index(m):] + [m])
            return
        if m in seen:
            return
        seen.add(m)
        stack.append(m)
        for n in sorted(graph[m]):
            visit(n)
        stack.pop()

    for m in sorted(SOURCES):
        visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


VALIDATION = ROOT / "validation"


@pytest.mark.skipif(not (VALIDATION / "physics_gen.py").exists(), reason="no generator")
def test_the_independent_generator_imports_nothing_of_the_package():
    tree = ast.parse((VALIDATION / "physics_gen.py").read_text(encoding="utf-8"))
    bad = [n.lineno for n in ast.walk(tree)
           if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("sdit_path")
           or isinstance(n, ast.Import) and any(a.name.startswith("sdit_path") for a in n.names)]
    assert not bad, f"validation/physics_gen.py imports sdit_path at lines {bad}"


def test_every_import_resolves():
    """Every import of the package, function-local ones included, names a module and
    names that exist (a local import left behind by a move fails only when its function
    runs)."""
    import importlib

    missing = []
    for name, imports in IMPORTS.items():
        for target, names, line in imports:
            try:
                mod = importlib.import_module(target)
            except ImportError as exc:
                missing.append(f"{SOURCES[name].relative_to(ROOT)}:{line}: {exc}")
                continue
            for n in names:
                if n != "*" and not hasattr(mod, n) \
                        and importlib.util.find_spec(f"{target}.{n}") is None:
                    missing.append(f"{SOURCES[name].relative_to(ROOT)}:{line}: {target} has no {n}")
    assert not missing, "\n".join(missing)


def _effect_names() -> tuple[str, ...]:
    from sdit_path.diagnose.effects import EFFECT_NAMES
    return EFFECT_NAMES


#: string literals that spell an effect's name but mean something else there: the
#: geometric model's squareness option and parameter kind
_NOT_AN_EFFECT = {("sdit_path.errormodel.model", "squareness"),
                  ("sdit_path.errormodel.errorset", "squareness"),
                  ("sdit_path.errormodel.chain", "squareness"),
                  ("sdit_path.reports.identification", "squareness")}


def test_only_the_effect_classes_and_the_simulator_name_an_effect():
    """Adding an effect is a class, its registry entry and its physics in the simulator
    and the generator; no other module of the package spells an effect's name."""
    names = set(_effect_names())
    bad = []
    for name, path in SOURCES.items():
        if name.startswith("sdit_path.diagnose.effects") or name == "sdit_path.sim.perturb":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Constant) and node.value in names
                    and (name, node.value) not in _NOT_AN_EFFECT):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    assert not bad, "effects named outside their classes:\n" + "\n".join(bad)


#: library effects the independent generator has no physics for yet (the set-up is in
#: every one of its recordings, so it is not listed)
_NOT_GENERATED = {"lateral_play"}


def test_the_simulator_and_the_generator_know_the_library():
    import physics_gen  # validation/ is on the path (conftest)

    from sdit_path.sim.perturb import IN_LIBRARY

    assert IN_LIBRARY == _effect_names(), "sim/perturb.py: IN_LIBRARY must list the library"
    generated = set(physics_gen.EFFECTS) | {"setup_offset", "bar_length"}
    assert set(_effect_names()) - generated == _NOT_GENERATED
