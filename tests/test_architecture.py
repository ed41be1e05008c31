"""The package's imports run one way, layer by layer, with no cycle (docs/ARCHITECTURE.md draws the layers).

Every ``import`` of a project module in ``steval_link`` and ``steval_viewer`` is read from the source (top level and
inside functions). A module may import its own layer or a lower one, never a higher one; no two modules import each
other through any chain; and an import inside a function is allowed only where it says why on its line (``#``
comment: start-up time, an optional dependency), since a hidden import is how the cycles of the past came in.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("steval_link", "steval_viewer")

#: layers from the bottom. A name ending in ``.*`` is a package and every module under it; any other name is that one
#: module exactly (``steval_link`` is the package's ``__init__`` only). A module named nowhere is in no layer.
LAYERS: list[tuple[str, ...]] = [
    (
        "steval_link",
        "steval_link.errors",
        "steval_link.constants",
        "steval_link.stop_signals",
        "steval_link.quat",
        "steval_link.units",
        "steval_link.fw_math",
        "steval_link._st_mahony_native",
        "steval_link.recordings",
    ),
    ("steval_link.link.*",),
    ("steval_link.estimators.*",),
    ("steval_link.emulation.*",),
    ("steval_link.live.*", "steval_link.analysis.*"),
    ("steval_viewer.*",),
    ("steval_link.api",),
    ("steval_link.cli.*",),
]
#: the one import that runs up: the package root lends ``steval_link.api``'s names, imported on first use
#: (``import steval_link as sl; sl.open_capture(...)`` for notebooks, while ``import steval_link`` stays cheap)
LAZY_FACADE = ("steval_link", "steval_link.api")


def find_layer(module: str, layers: list[tuple[str, ...]] = LAYERS) -> int | None:
    """The layer that names ``module`` (itself, or a ``pkg.*`` it is in or is), or None."""
    best, best_len = None, -1
    for i, names in enumerate(layers):
        for name in names:
            if name.endswith(".*"):
                pkg = name[:-2]
                hit = module == pkg or module.startswith(pkg + ".")
            else:
                pkg, hit = name, module == name
            if hit and len(pkg) > best_len:
                best, best_len = i, len(pkg)
    return best


def layer_of(module: str) -> int:
    best = find_layer(module)
    assert best is not None, f"{module} is in no layer: add it to LAYERS and to docs/ARCHITECTURE.md"
    return best


def modules_outside_layers(modules, layers: list[tuple[str, ...]] = LAYERS) -> list[str]:
    return sorted(m for m in modules if find_layer(m, layers) is None)


def package_dir(root: Path, pkg: str) -> Path:
    """The folder of import package ``pkg``: ``root/pkg``, or where pyproject's package-dir maps it."""
    import tomllib

    pyproject = root / "pyproject.toml"
    if pyproject.is_file():
        mapped = (
            tomllib.loads(pyproject.read_text(encoding="utf-8"))
            .get("tool", {})
            .get("setuptools", {})
            .get("package-dir", {})
            .get(pkg)
        )
        if mapped:
            return root / mapped
    return root / pkg


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        base = package_dir(root, pkg)
        for path in base.rglob("*.py"):
            parts = [pkg, *path.relative_to(base).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def imports_of(path: Path, modules: dict[str, Path]) -> list[tuple[str, int, bool, str]]:
    """(imported project module, line, inside a function, the source line) of every project import in ``path``."""
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    tree = ast.parse(source)
    found = []

    def visit(node, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            names: list[str] = []
            if isinstance(child, ast.Import):
                names = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
                names = [child.module] + [f"{child.module}.{a.name}" for a in child.names]
            for name in names:
                target = name
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target.split(".")[0] in PACKAGES:
                    found.append((target, child.lineno, in_function, lines[child.lineno - 1]))
            visit(child, inner)

    visit(tree, False)
    return found


@pytest.fixture(scope="module")
def project():
    """(every project module and its path, every module's project imports): the tree is parsed once."""
    modules = project_modules()
    return modules, {name: imports_of(path, modules) for name, path in modules.items()}


def test_imports_run_down_the_layers_never_up(project):
    modules, imports = project
    up = []
    for name, path in sorted(modules.items()):
        mine = layer_of(name)
        for target, line, in_function, _ in imports[name]:
            if target == name or name.startswith(target + "."):  # a package's own __init__ / parent package
                continue
            if (name, target) == LAZY_FACADE and in_function:
                continue
            if layer_of(target) > mine:
                up.append(f"{path.relative_to(ROOT)}:{line} imports {target} (layer {layer_of(target)} > {mine})")
    assert not up, "imports that run up the layers:\n" + "\n".join(up)


def test_no_import_cycle(project):
    modules, imports = project
    graph = {}
    for name, path in modules.items():
        graph[name] = {t for t, *_ in imports[name] if t != name and not name.startswith(t + ".")}
    # Tarjan's strongly connected components
    index, low, stack, on_stack, cycles, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                strong(w)
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
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    assert not cycles, f"modules that import each other: {cycles}"


def test_imports_inside_functions_say_why(project):
    modules, imports = project
    silent = []
    for name, path in sorted(modules.items()):
        for target, line, in_function, text in imports[name]:
            if in_function and "#" not in text:
                silent.append(f"{path.relative_to(ROOT)}:{line}: {text.strip()}")
    assert not silent, "project imports inside functions without a reason on the line:\n" + "\n".join(silent)


def test_every_module_is_in_a_layer(project):
    modules, _ = project
    assert len(modules) > 100 and {"steval_link.link.decoder", "steval_viewer"} <= set(modules)  # the real tree
    outside = modules_outside_layers(modules)
    assert not outside, f"modules in no layer (add them to LAYERS and to docs/ARCHITECTURE.md): {outside}"


def test_a_module_outside_every_layer_is_reported(tmp_path):
    """The layer check fails for a new top-level module or a package next to a layer's, in a real module tree (its
    viewer in a folder of another name, mapped by pyproject's package-dir)."""
    for rel in (
        "steval_link/__init__.py",
        "steval_link/errors.py",
        "steval_link/link/__init__.py",
        "steval_link/link/decoder.py",
        "steval_link/stray.py",
        "steval_link/linkage/__init__.py",
        "steval_link/linkage/x.py",
        "viewer/__init__.py",
        "viewer/scene.py",
    ):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    (tmp_path / "pyproject.toml").write_text('[tool.setuptools.package-dir]\n"steval_viewer" = "viewer"\n')
    modules = project_modules(tmp_path)
    assert {"steval_link.link.decoder", "steval_viewer", "steval_viewer.scene"} <= set(modules)  # a mapped folder
    assert modules_outside_layers(modules) == ["steval_link.linkage", "steval_link.linkage.x", "steval_link.stray"]
    assert find_layer("steval_link.link.decoder") == 1 and find_layer("steval_link.link") == 1
    assert find_layer("steval_link") == 0 and find_layer("steval_viewer.scene") == 5
    assert find_layer("steval_link.cli.app") == 7 and find_layer("steval_link.api") == 6
    assert find_layer("steval_link.api.helpers") is None  # a module's name is not a package's
    assert find_layer("steval_link.errors_extra") is None and find_layer("steval_viewer2") is None
    with pytest.raises(AssertionError, match="steval_link.stray is in no layer"):
        layer_of("steval_link.stray")


def documented_name(path: Path, root: Path = ROOT) -> str:
    """How docs/ARCHITECTURE.md names a source file: ``link/decoder.py`` inside the package, ``steval_link/x.py``
    at its top, ``viewer/x.py`` for the Rerun side."""
    rel = path.relative_to(root).as_posix()
    inner = rel.removeprefix("steval_link/")
    return inner if "/" in inner else rel


def names_in_module_table(doc: str) -> list[str]:
    """Every back-quoted name in the first cell of the rows of the doc's module tables."""
    section = doc.split("## Modules and their contracts", 1)[1].split("\n## ", 1)[0]
    names = []
    for line in section.splitlines():
        if line.startswith("| `"):
            names += line.split("|")[1].split("`")[1::2]
    return names


def test_every_module_is_named_once_in_the_architecture_doc():
    """A newcomer finds each module once in docs/ARCHITECTURE.md, in the order the data passes through them."""
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    named = names_in_module_table(doc)
    files = [
        p
        for top in ("steval_link", "viewer")
        for p in sorted((ROOT / top).rglob("*"))
        if p.suffix in (".py", ".c") and p.name != "__init__.py" and "recordings" not in p.parts
    ]
    expected = {documented_name(p) for p in files}
    missing = sorted(expected - set(named))
    twice = sorted({n for n in named if named.count(n) > 1})
    stale = sorted(n for n in set(named) - expected if n.endswith((".py", ".c")))
    assert not missing, f"modules not in docs/ARCHITECTURE.md: {missing}"
    assert not twice, f"modules named more than once: {twice}"
    assert not stale, f"the doc names modules that do not exist: {stale}"


def test_the_doc_check_sees_a_missing_module():
    doc = (
        "## Modules and their contracts\n| `link/decoder.py`, `link/frames.py` | x |\n| `viewer/a.py` | y |\n## Tests\n"
    )
    assert names_in_module_table(doc) == ["link/decoder.py", "link/frames.py", "viewer/a.py"]
    assert documented_name(ROOT / "steval_link" / "link" / "decoder.py") == "link/decoder.py"
    assert documented_name(ROOT / "steval_link" / "quat.py") == "steval_link/quat.py"
