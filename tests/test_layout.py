"""The joints between modules: no module imports another's private names, no
import cycles among slr_ray's modules (imports at module level), and
docstrings cite only what users have."""

import ast
import pathlib

PKG = pathlib.Path(__file__).resolve().parents[1] / "slr_ray"


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _resolve(module, node):
    """Absolute module name of an ImportFrom inside ``module``."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    is_pkg = False
    base = base[: len(base) - node.level + (1 if is_pkg else 0)]
    return ".".join(base + ([node.module] if node.module else []))


def _package_of(mod, path):
    return mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]


def _imports(mod, path, top_level_only):
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            if node.level:
                pkg = _package_of(mod, path).split(".")
                target = ".".join(pkg[: len(pkg) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            yield node, target


def test_no_module_imports_another_modules_private_names():
    bad = []
    for mod, path in _modules():
        for node, target in _imports(mod, path, top_level_only=False):
            if not target.startswith("slr_ray"):
                continue
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    bad.append(f"{mod}: from {target} import {alias.name}")
    assert not bad, "\n".join(bad)


def test_no_import_cycles_between_modules():
    graph = {}
    for mod, path in _modules():
        deps = set()
        for node, target in _imports(mod, path, top_level_only=True):
            if target.startswith("slr_ray"):
                deps.add(target)
                for alias in node.names:  # "from . import x" may name a submodule
                    deps.add(f"{target}.{alias.name}")
        graph[mod] = {d for d in deps if d != mod}
    known = set(graph)
    graph = {m: {d for d in ds if d in known} for m, ds in graph.items()}
    # a package's __init__ importing its own submodules is not a cycle by itself
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in graph[m]:
            if m.startswith(d + ".") or d.startswith(m + "."):
                continue  # package <-> its own submodule
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, cycles


def test_docstrings_do_not_cite_files_users_do_not_have():
    bad = [str(p.relative_to(PKG)) for _, p in _modules() if "DESIGN" in p.read_text()]
    assert not bad, bad


def test_figures_leave_matplotlib_state_alone():
    """Only slr_ray.plotting draws, and it never switches the backend or uses pyplot."""
    bad = []
    for mod, path in _modules():
        text = path.read_text()
        if "matplotlib.use(" in text or "import matplotlib.pyplot" in text or "import pyplot" in text:
            bad.append(f"{mod}: matplotlib.use or pyplot")
        if mod != "slr_ray.plotting" and "import matplotlib" in text:
            bad.append(f"{mod}: imports matplotlib (figures belong in slr_ray.plotting)")
    assert not bad, "\n".join(bad)


def test_paper_numbers_are_named_once():
    """The paper's constants appear as numbers in code only in slr_ray.paper
    (and the pattern presets, which are the paper's patterns by name)."""
    paper_numbers = {1.65, 50_000, 17.5, 0.144, 0.0144, 0.00576, 0.036}
    bad = []
    for mod, path in _modules():
        if mod in ("slr_ray.paper", "slr_ray.pattern"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and type(node.value) in (int, float) \
                    and node.value in paper_numbers:
                bad.append(f"{mod}:{node.lineno}: {node.value}")
    assert not bad, "\n".join(bad)
