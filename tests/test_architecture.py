"""The layout holds: layers import only downward, no import cycle (function-level imports
included), modules stay small, and library code sets no global flags (docs/architecture.md)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "adaptive_cal"
# lowest first: a module may import from its own layer and the layers before it
LAYERS = ("gaussian", "effects", "formats", "planning", "hardware", "cell", "simulation",
          "analysis", "report", "run", "study", "cli")
MAX_LINES = 350


def _modules() -> dict[str, Path]:
    out = {}
    for f in PACKAGE.rglob("*.py"):
        parts = list(f.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """Modules of the package that ``name`` imports, at any depth of the file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_pkg = path.name == "__init__.py"
    here = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = here[: len(here) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        if isinstance(node, ast.ImportFrom):  # from pkg import module: the module, not pkg
            subs = [t for t in targets[1:] if t in MODULES]
            targets = subs if len(subs) == len(node.names) else targets
        for t in targets:
            if t in MODULES and t != name:
                found.add(t)
    # importing a.b.c runs a/__init__ and a/b/__init__ too; those edges are not ours to count
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _layer(name: str) -> int | None:
    parts = name.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_every_module_sits_in_a_layer():
    loose = [n for n in MODULES if n not in ("adaptive_cal", "adaptive_cal.__main__")
             and _layer(n) is None]
    assert not loose, f"modules outside the layers {LAYERS}: {loose}"
    # ``python -m adaptive_cal``: the command line's entry, above every layer, and nothing else
    assert GRAPH["adaptive_cal.__main__"] <= {"adaptive_cal.cli"}


def test_nothing_imports_upward():
    upward = [f"{a} -> {b}" for a, deps in GRAPH.items() for b in deps
              if _layer(a) is not None and _layer(b) is not None and _layer(b) > _layer(a)]
    assert not upward, "imports that run upward:\n" + "\n".join(sorted(upward))


def test_no_import_cycle():
    """Tarjan's strongly connected components over every import edge (function-level too)."""
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in GRAPH:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_the_checker_sees_function_level_and_relative_imports(tmp_path):
    src = "def f():\n    from ..gaussian import belief\n    import adaptive_cal.cell.schema\n"
    p = tmp_path / "x.py"
    p.write_text(src)
    assert _imports("adaptive_cal.planning.x", p) == {"adaptive_cal.gaussian.belief",
                                                       "adaptive_cal.cell.schema"}


@pytest.mark.parametrize("name", sorted(MODULES))
def test_module_is_small(name):
    lines = len(MODULES[name].read_text(encoding="utf-8").splitlines())
    assert lines <= MAX_LINES, f"{MODULES[name]} has {lines} lines (at most {MAX_LINES})"


GLOBAL_FLAGS = ("jax.config.update", "matplotlib.use(", "import matplotlib.pyplot",
                "from matplotlib import pyplot", "os.environ[", "os.environ.setdefault",
                "np.random.seed(", "default_rng()")


@pytest.mark.parametrize("name", sorted(n for n in MODULES if not n.startswith("adaptive_cal.cli")))
def test_library_code_sets_no_global_flags(name):
    """x64, BLAS threads and the matplotlib backend belong to the CLI and the tests; randomness
    is passed in. (``use_float64`` at the package root is the one documented switch.)"""
    text = MODULES[name].read_text(encoding="utf-8")
    if name == "adaptive_cal":
        text = text.replace('jax.config.update("jax_enable_x64", True)', "")
    hits = [flag for flag in GLOBAL_FLAGS if flag in text]
    assert not hits, f"{MODULES[name]} sets global state: {hits}"
