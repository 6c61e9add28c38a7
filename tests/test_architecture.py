"""The package's layout promises, checked on its source (AST), not by eye."""

import ast
from pathlib import Path

import pytest

import mutloc

ROOT = Path(mutloc.__file__).resolve().parent
FILES = sorted(ROOT.rglob("*.py"))


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path):
    """(absolute module, imported names, line) of every ``from X import ...``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = _module_name(path)
    if path.name != "__init__.py":
        pkg = pkg.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = pkg.split(".")
            if node.level:
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            yield mod, [a.name for a in node.names], node.lineno
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, [], node.lineno


def _is_submodule(mod: str, name: str) -> bool:
    return (ROOT.parent / Path(*f"{mod}.{name}".split("."))).with_suffix(".py").exists()


def test_no_private_name_crosses_modules():
    bad = []
    for f in FILES:
        for mod, names, line in _imports(f):
            if not mod.startswith("mutloc"):
                continue
            for n in names:
                if n.startswith("_") and not n.startswith("__") and not _is_submodule(mod, n):
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {n} from {mod}")
    assert not bad, "\n".join(bad)


#: A dependency's private module mutloc uses, where, and why (each with a fallback to the public API).
THIRD_PARTY_PRIVATE = {
    ("live/dds.py", "cyclonedds._clayer"): "taking samples as bytes in bulk (each undecodable one still counted); "
                                           "without it, the public take of one sample at a time",
}


def test_private_modules_are_private_to_their_package():
    """``mutloc.x._y`` is imported only from inside ``mutloc.x``; a
    dependency's private module only where :data:`THIRD_PARTY_PRIVATE` says."""
    bad = []
    for f in FILES:
        here = _module_name(f)
        for mod, names, line in _imports(f):
            full = [mod] + [f"{mod}.{n}" for n in names if _is_submodule(mod, n)]
            for m in full:
                parts = m.split(".")
                for i, p in enumerate(parts):
                    if p.startswith("_") and not p.startswith("__") and i > 0:
                        owner = ".".join(parts[:i])
                        if (str(f.relative_to(ROOT)), m) in THIRD_PARTY_PRIVATE:
                            continue
                        if not (here == owner or here.startswith(owner + ".")):
                            bad.append(f"{f.relative_to(ROOT)}:{line} imports {m}")
    assert not bad, "\n".join(bad)


CORE_FORBIDDEN = ("mutloc.io", "mutloc.cli", "mutloc.track", "mutloc.detect", "mutloc.sim",
                  "mutloc.experiments", "mutloc.baselines", "mutloc.api", "yaml", "matplotlib", "tqdm",
                  "rosbags")


def test_core_imports_no_io_and_nothing_around_it():
    bad = []
    for f in sorted((ROOT / "core").rglob("*.py")):
        for mod, _names, line in _imports(f):
            if any(mod == x or mod.startswith(x + ".") for x in CORE_FORBIDDEN):
                bad.append(f"{f.relative_to(ROOT)}:{line} imports {mod}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("path", sorted((ROOT / "detect").rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_detector_files_stay_small(path):
    n = len(path.read_text(encoding="utf-8").splitlines())
    assert n <= 650, f"{path.relative_to(ROOT)} has {n} lines: split it into stages"


@pytest.mark.parametrize("first", ["attribute", "subpackage"])
def test_mutloc_track_is_the_subpackage_whatever_is_imported_first(first):
    """``mutloc.track`` is the subpackage before and after ``import
    mutloc.track``; the tracker is ``mutloc.track_streams`` (run in a fresh
    interpreter: the order of imports is what is tested)."""
    import subprocess
    import sys

    steps = {"attribute": "import mutloc\nfirst = mutloc.track\nfn = mutloc.track_streams\nimport mutloc.track\n",
             "subpackage": "import mutloc.track\nimport mutloc\nfirst = mutloc.track\nfn = mutloc.track_streams\n"}
    code = steps[first] + (
        "import types\nimport mutloc.track.tracker as tracker\n"
        "assert isinstance(first, types.ModuleType) and first is mutloc.track, first\n"
        "assert fn is tracker.track and mutloc.track_log is tracker.track_log\n"
        "from mutloc import track\nassert track is mutloc.track\nprint('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-800:]


def _optional_imports(path: Path):
    """(package, line, at module level) of every import of a package of
    :data:`mutloc._extras.PACKAGES`; module level: not inside a function
    (a class body runs at import too)."""
    from mutloc._extras import PACKAGES

    def walk(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                tops = [a.name.partition(".")[0] for a in child.names]
            elif isinstance(child, ast.ImportFrom) and not child.level:
                tops = [(child.module or "").partition(".")[0]]
            else:
                tops = []
            for top in tops:
                if top in PACKAGES:
                    yield top, child.lineno, not in_function
            yield from walk(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                                          ast.Lambda)))

    yield from walk(ast.parse(path.read_text(encoding="utf-8")), False)


def _required(path: Path) -> set[str]:
    """Packages named by a ``require("package", ...)`` call in the file."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if (isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "require"
                and node.args and isinstance(node.args[0], ast.Constant)):
            out.add(node.args[0].value)
    return out


def test_optional_packages_are_imported_lazily_through_require():
    """``pip install mutloc`` (no extra) imports every module: none imports an
    optional package (or pupil-apriltags) at module level, and a module that
    imports one in a function also calls ``mutloc._extras.require`` for it, so
    a missing one is a one-line error naming its extra."""
    bad = []
    for f in FILES:
        required = _required(f)
        for top, line, module_level in _optional_imports(f):
            if module_level:
                bad.append(f"{f.relative_to(ROOT)}:{line} imports {top} at module level")
            elif top not in required:
                bad.append(f"{f.relative_to(ROOT)}:{line} imports {top} without require({top!r}, ...)")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package", ["mutloc.track", "mutloc.core", "mutloc.io", "mutloc.detect", "mutloc.live"])
def test_no_import_circle_among_a_package_s_modules(package):
    """Within a subpackage the modules import each other one way only --
    counting imports inside functions and under TYPE_CHECKING, which hide a
    circle rather than remove it (issue: filtering <-> hindsight, frames <->
    second_look)."""
    mods = {_module_name(p): p for p in FILES if _module_name(p).startswith(package + ".")}

    def target(mod, names):
        # "from .x import y" names module x, or module x.y where y is a submodule
        return [f"{mod}.{n}" if f"{mod}.{n}" in mods else mod for n in names] or [mod]

    graph = {m: {t for mod, names, _ in _imports(p) for t in target(mod, names) if t in mods and t != m}
             for m, p in mods.items()}
    # Tarjan's strongly connected components
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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

    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, cycles
